"""Errors of training: checkpoints, interruptions, replay-buffer arguments, world worker processes."""

from __future__ import annotations

from pipeline.errors import MrlError


class CheckpointError(MrlError):
    """A training checkpoint is missing, corrupt or inconsistent; names the file."""

    def __init__(self, path: str, problem: str) -> None:
        self.path = path
        self.problem = problem
        super().__init__(f"{path}: {problem}")


class TrainingInterrupted(MrlError):
    """Training stopped on a signal; the last checkpoint was written."""

    interrupted = True

    def __init__(self, checkpoint: str, steps: int) -> None:
        self.checkpoint = checkpoint
        self.steps = steps
        super().__init__(f"training interrupted after {steps} world steps; checkpoint kept at {checkpoint}")


class PrioritizedReplayError(MrlError, ValueError):
    """A prioritized-replay argument is out of range or does not fit the rest of the set-up."""

    def __init__(self, argument: str, value: object, allowed: str) -> None:
        self.argument = argument
        self.value = value
        self.allowed = allowed
        super().__init__(f"{argument} = {value!r}: {allowed}")


class WorldWorkerError(MrlError):
    """A process that steps some of the training worlds failed or vanished; carries its traceback or exit code."""

    def __init__(self, pid: int | None, problem: str) -> None:
        self.pid = pid
        self.problem = problem
        super().__init__(f"training world worker (pid {pid}) failed: {problem}")
