"""Errors of rollouts: stopped evaluations and deployments, fleets that are not ready or not ours."""

from __future__ import annotations

from pipeline.core.episode import EpisodeResult
from pipeline.errors import MrlError, RuntimeFault


class EvaluationInterrupted(MrlError):
    """Evaluation stopped on a signal; `results` holds the episodes finished before it."""

    interrupted = True

    def __init__(self, results: list[EpisodeResult]) -> None:
        self.results = results
        super().__init__(f"evaluation interrupted after {len(results)} finished episode(s); the recording is kept")


class DeployAborted(RuntimeFault):
    """The deployment stopped early; robots were sent zero velocity and the recording was closed. `results` holds
    every episode run, the one cut short included (counted as aborted)."""

    def __init__(self, reason: str, results: list[EpisodeResult], interrupted: bool = False) -> None:
        self.reason = reason
        self.results = results
        self.interrupted = interrupted
        super().__init__(f"deployment stopped after {len(results)} episode(s): {reason}")


class FleetNotReady(RuntimeFault):
    """Robots did not appear, did not confirm a reset, or sent no data in time; names them."""


class FleetConflict(RuntimeFault):
    """Robots that this deployment did not start publish on the fleet's topics (a stray twin, another user)."""

    def __init__(self, domain_id: int, seen: list[str], hint: str) -> None:
        self.domain_id = domain_id
        self.seen = tuple(seen)
        super().__init__(f"DDS domain {domain_id} already has {'; '.join(seen)}: {hint}")


class FleetConfigMismatch(MrlError):
    """The parameters and the fleet file describe different worlds."""
