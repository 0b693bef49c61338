"""The project's robot models (registered in ``nao_trainer.registry.BUILTIN``): ``nao``, ``pepper``."""
