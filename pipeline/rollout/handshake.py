"""The reset handshake that opens every episode on a fleet.

The runner asks for episode k with its seed on ``/mrl/reset`` and waits for ``/mrl/reset_done`` with the
same episode number (the twin places its robots and answers); on real robots an operator confirms
instead. No answer in time is FleetNotReady naming the episode; a fleet that dies meanwhile is
reported by `check_alive`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from pipeline.rollout.errors import FleetNotReady


class ResetHandshake:
    """Requests resets with `publish(episode, seed)` and waits for `confirmed(episode, seed)` (transport thread).

    With `operator` set, a reset is confirmed by calling it with the episode number instead (it returns
    when the operator has placed the robots).
    """

    def __init__(
        self,
        publish: Callable[[int, int], None],
        timeout_s: float,
        check_alive: Callable[[], None] = lambda: None,
        operator: Callable[[int], None] | None = None,
    ) -> None:
        self.publish = publish
        self.timeout_s = timeout_s
        self.check_alive = check_alive
        self.operator = operator
        self._done: dict[int, int] = {}
        self._cv = threading.Condition()

    def confirmed(self, episode: int, seed: int) -> None:
        """The fleet reports that episode `episode` is reset (called from the transport's thread)."""
        with self._cv:
            self._done[episode] = seed
            self._cv.notify_all()

    def request(self, episode: int, seed: int) -> None:
        """Reset the fleet for `episode`; returns once it is confirmed."""
        if self.operator is not None:
            self.operator(episode)
            return
        self.publish(episode, seed)
        deadline = time.monotonic() + self.timeout_s
        with self._cv:
            while episode not in self._done:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise FleetNotReady(
                        f"the fleet did not confirm the reset of episode {episode} within {self.timeout_s:g} s"
                    )
                self._cv.wait(min(left, 0.1))
                self.check_alive()
