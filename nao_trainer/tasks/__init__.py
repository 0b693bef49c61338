"""Tasks: what a session trains. Each task is a folder with its rules, dialogue events, row fields and settings,
registered once by name in ``nao_trainer.registry.BUILTIN`` (or by a package through the entry-point group
``nao_trainer.tasks``). The session (``nao_trainer.session``) is generic over ``tasks.base.Task``."""
