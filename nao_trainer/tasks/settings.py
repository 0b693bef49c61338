"""The ``task`` section of a study config, declared once (``core.settings``): which task, and its own settings.

``task.name`` is resolved through the registry (``nao-trainer plugins`` lists the tasks); ``task.settings`` is
the task's own mapping, checked by the task's ``Settings`` class when it has one (``TaskSettings.build_task``).
Light on purpose: the registry loads a task only when it is used.
"""
from __future__ import annotations

from typing import Any

from nao_trainer import registry
from nao_trainer.core.settings import SettingError, build, setting, settings
from nao_trainer.errors import ConfigError


def _registered_task(value: str) -> str | None:
    try:
        registry.spec("task", value)
    except ConfigError as exc:
        return str(exc)
    return None


@settings
class TaskSettings:
    """The ``task`` section of a study config, validated."""

    name: str = setting(registry.default("task"), kind=str, check=_registered_task,
                        doc="the task plug-in (nao-trainer plugins lists them): sequence, nback, ...")
    settings: dict = setting(factory=dict, kind=dict, free=True,
                             doc="the task's own settings (its Settings class; nao-trainer plugins)")

    def build_task(self) -> Any:
        """The configured task, built with its own settings (one ``ConfigError`` line for a bad key)."""
        cls = registry.load("task", self.name)
        own = getattr(cls, "Settings", None)
        if own is None:
            if self.settings:
                raise ConfigError(f"key 'task.settings': task {self.name!r} has no settings, got {sorted(self.settings)}")
            return cls()
        try:
            return cls(build(own, dict(self.settings), "task.settings"))
        except SettingError as exc:
            raise ConfigError(str(exc)) from None
