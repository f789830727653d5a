"""Errors of the ROS 2 transport: DDS settings and backends."""

from __future__ import annotations

from pipeline.errors import MrlError


class TransportError(MrlError):
    """The network transport cannot do what was asked; names the topic or setting involved."""

    def __init__(self, where: str, problem: str) -> None:
        self.where = where
        self.problem = problem
        super().__init__(f"{where}: {problem}")


class NetworkSettingsError(TransportError):
    """A network setting has a value that is not allowed; names the setting and what is allowed."""

    def __init__(self, setting: str, value: object, allowed: str) -> None:
        self.setting = setting
        self.value = value
        self.allowed = allowed
        super().__init__(f"network setting {setting} = {value!r}", allowed)


class BackendUnavailableError(TransportError):
    """The requested transport backend cannot run in this Python environment."""
