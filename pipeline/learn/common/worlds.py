"""Parallel simulated worlds stepped in lockstep, with per-robot transitions for the learners.

Each world is one :class:`~pipeline.sim.env.MultiRobotSim`. A world's episode ends when every
robot is done (goal or collision) or at the step limit; the world then starts its next episode
with a seed drawn from the trainer's seed, so a training run is fixed by its seed. Robots that are
done before their world's episode ends are *inactive*: their transitions are not training data.

The worlds may be stepped by worker processes (`workers` > 1: each holds a contiguous share of the
worlds and steps them while the others step theirs). Seeds and perturbed starts are always drawn
here, in world order, and a world's episode depends on its seed and starts alone, so the transitions
are the same to the bit whatever the number of workers.
"""

from __future__ import annotations

import contextlib
import itertools
import multiprocessing as mp
import signal
import traceback
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from pipeline.core.scenario import Scenario, perturbed_starts
from pipeline.learn.errors import WorldWorkerError
from pipeline.params import WorldConfig
from pipeline.sim.env import MultiRobotSim


@dataclass(frozen=True)
class EpisodeRecord:
    """One finished episode of one world; per-robot arrays are (n_robots,)."""

    world: int
    seed: int
    steps: int
    returns: np.ndarray
    reached: np.ndarray
    collided: np.ndarray
    team_success: bool

    @property
    def success(self) -> np.ndarray:
        """(n_robots,) robots inside their goal without a collision."""
        return np.asarray(self.reached & ~self.collided)


@dataclass(frozen=True)
class WorldsStep:
    """The outcome of one lockstep control step of every world; shapes (n_worlds, n_robots[, obs_size]).

    `next_obs` is each robot's observation at the end of the step (before any reset): the
    transition's successor. `obs` is what the policy sees next: the first observation of a new
    episode in worlds that ended.
    """

    obs: np.ndarray
    next_obs: np.ndarray
    reward: np.ndarray
    active: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    world_ended: np.ndarray
    finished: list[EpisodeRecord]


TRAIN_SEED_MIN = 2**30
"""Training episodes' seeds start here; evaluation, selection and deployment seeds lie below."""


@dataclass(frozen=True)
class _Stepped:
    """What stepping a share of the worlds gives back; leading axis: the share's worlds."""

    obs: np.ndarray
    reward: np.ndarray
    active: np.ndarray
    done: np.ndarray
    reached: np.ndarray
    collided: np.ndarray
    truncated: np.ndarray
    team_success: np.ndarray
    steps: np.ndarray


class _Share:
    """Some of the worlds, stepped together in one process."""

    def __init__(self, sims: list[MultiRobotSim]) -> None:
        self.sims = sims

    def reset(self, requests: list[tuple[int, int, np.ndarray | None]]) -> list[np.ndarray]:
        """Reset world k (index in the share) with (k, seed, starts or None); the first observations."""
        return [self.sims[k].reset(seed, starts) for k, seed, starts in requests]

    def path_bearings(self, ahead_m: float) -> np.ndarray:
        """(worlds in the share, n_robots) :meth:`MultiRobotSim.path_bearing` of each world."""
        return np.stack([sim.path_bearing(ahead_m) for sim in self.sims])

    def others_in_frame(self) -> np.ndarray:
        """(worlds in the share, n_robots, n_robots - 1, 2) :meth:`MultiRobotSim.others_in_frame` of each world."""
        return np.stack([sim.others_in_frame() for sim in self.sims])

    def step(self, actions: np.ndarray) -> _Stepped:
        results = [sim.step(a) for sim, a in zip(self.sims, actions, strict=True)]
        judged = [r.judge for r in results]
        return _Stepped(
            obs=np.stack([r.obs for r in results]),
            reward=np.stack([j.reward for j in judged]),
            active=np.stack([j.active for j in judged]),
            done=np.stack([j.done for j in judged]),
            reached=np.stack([j.reached for j in judged]),
            collided=np.stack([j.collided for j in judged]),
            truncated=np.array([j.truncated for j in judged]),
            team_success=np.array([j.team_success for j in judged]),
            steps=np.array([sim.judge.steps for sim in self.sims]),
        )


def _serve(conn: Connection, scenario: Scenario, world: WorldConfig, n_worlds: int) -> None:
    """A worker process: builds its share of the worlds, then answers step and reset requests until closed.

    Ctrl-C reaches the whole process group: the trainer handles it (checkpoint, then closes its workers)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        share = _Share([MultiRobotSim(scenario, world) for _ in range(n_worlds)])
        conn.send(("ready", None))
    except Exception:
        conn.send(("error", traceback.format_exc()))
        return
    while True:
        try:
            verb, arg = conn.recv()
        except EOFError:
            return
        if verb == "close":
            return
        try:
            if verb == "step":
                conn.send(("ok", share.step(arg)))
            elif verb == "bearings":
                conn.send(("ok", share.path_bearings(arg)))
            elif verb == "others":
                conn.send(("ok", share.others_in_frame()))
            else:
                conn.send(("ok", share.reset(arg)))
        except Exception:
            conn.send(("error", traceback.format_exc()))


class _Worker:
    """A share of the worlds in a process of its own (spawned: no state of the trainer is inherited)."""

    def __init__(self, scenario: Scenario, world: WorldConfig, n_worlds: int) -> None:
        ctx = mp.get_context("spawn")
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_serve, args=(child, scenario, world, n_worlds), daemon=True)
        self.process.start()
        child.close()

    def send(self, verb: str, arg: Any) -> None:
        try:
            self.conn.send((verb, arg))
        except (BrokenPipeError, OSError) as e:
            raise WorldWorkerError(self.process.pid, f"the process is gone (exit code {self.process.exitcode})") from e

    def receive(self) -> Any:
        try:
            status, value = self.conn.recv()
        except (EOFError, OSError) as e:
            raise WorldWorkerError(self.process.pid, f"the process is gone (exit code {self.process.exitcode})") from e
        if status == "error":
            raise WorldWorkerError(self.process.pid, value)
        return value

    def close(self) -> None:
        if self.process.is_alive():
            with contextlib.suppress(BrokenPipeError, OSError):
                self.conn.send(("close", None))
            self.process.join(timeout=5)
            if self.process.is_alive():
                self.process.kill()
                self.process.join()
        self.conn.close()


class VecWorlds:
    """`n_worlds` copies of one scenario, stepped together (by `workers` processes when more than 1)."""

    def __init__(
        self,
        scenario: Scenario,
        world: WorldConfig,
        n_worlds: int,
        seed: int,
        start_xy_m: float = 0.0,
        start_yaw_rad: float = 0.0,
        workers: int = 1,
        remote: bool = False,
    ) -> None:
        """`start_xy_m`, `start_yaw_rad`: each episode starts every robot this far (uniformly) from its start pose.
        `workers`: processes that step the worlds (1: this process, unless `remote`; at most `n_worlds` are used).
        `remote`: the worlds live in worker processes even where there is one, so that `step_async` lets this
        process work while they step."""
        if n_worlds < 1:
            raise ValueError(f"n_worlds must be >= 1, got {n_worlds}")
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.scenario = scenario
        self.config = world
        self.n_worlds = n_worlds
        self.n_robots = scenario.n_robots
        probe = MultiRobotSim(scenario, world)
        self.layout = probe.layout
        self.obs_size = probe.layout.size
        self.codec = probe.codec
        self.obs_low, self.obs_high = probe.obs_low, probe.obs_high
        self.random_layouts = probe.random_layouts
        n_workers = min(workers, n_worlds)
        bounds = np.linspace(0, n_worlds, n_workers + 1).round().astype(int)
        self._shares = [(int(a), int(b)) for a, b in itertools.pairwise(bounds)]
        self._workers: list[_Worker] = []
        self._local: _Share | None = None
        if n_workers == 1 and not remote:
            self._local = _Share([probe] + [MultiRobotSim(scenario, world) for _ in range(n_worlds - 1)])
        else:
            self._workers = [_Worker(scenario, world, b - a) for a, b in self._shares]
            for w in self._workers:
                w.receive()
        self._seeds = np.random.default_rng(seed)
        self._starts = np.random.default_rng([seed, 1])
        self.start_xy_m = start_xy_m
        self.start_yaw_rad = start_yaw_rad
        self._episode_seed = np.zeros(n_worlds, dtype=np.int64)
        self._returns = np.zeros((n_worlds, self.n_robots))
        self._obs = np.zeros((n_worlds, self.n_robots, self.obs_size), dtype=np.float32)
        self._pending = False

    @property
    def sims(self) -> list[MultiRobotSim]:
        """The worlds themselves, where they live in this process (`workers` == 1)."""
        if self._local is None:
            raise RuntimeError("the worlds live in worker processes")
        return self._local.sims

    def close(self) -> None:
        """Stop the worker processes (nothing to do without them)."""
        for w in self._workers:
            w.close()
        self._workers = []

    def __enter__(self) -> VecWorlds:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _next_seed(self) -> int:
        # training seeds are >= TRAIN_SEED_MIN, evaluation seeds below it: random layouts drawn from the seeds
        # of evaluation episodes are never among those trained on
        return int(self._seeds.integers(TRAIN_SEED_MIN, 2**31 - 1))

    def _reset_worlds(self, worlds: list[int]) -> None:
        """Start the next episode of `worlds` (in this order: seeds and starts are drawn in it)."""
        requests: list[list[tuple[int, int, np.ndarray | None]]] = [[] for _ in self._shares]
        for j in worlds:
            self._episode_seed[j] = self._next_seed()
            starts = (
                None
                if self.random_layouts  # the layout's own starts are already a draw
                else perturbed_starts(self.scenario, self._starts, self.start_xy_m, self.start_yaw_rad)
            )
            s = next(i for i, (a, b) in enumerate(self._shares) if a <= j < b)
            requests[s].append((j - self._shares[s][0], int(self._episode_seed[j]), starts))
        if self._local is not None:
            answers = [self._local.reset(requests[0])]
        else:
            busy = [s for s, r in enumerate(requests) if r]
            for s in busy:
                self._workers[s].send("reset", requests[s])
            answers = [self._workers[s].receive() if s in busy else [] for s in range(len(self._shares))]
        for (a, _), share_requests, obs in zip(self._shares, requests, answers, strict=True):
            for (k, _, _), o in zip(share_requests, obs, strict=True):
                self._obs[a + k] = o

    def reset(self) -> np.ndarray:
        """Start every world's first episode; returns observations (n_worlds, n_robots, obs_size)."""
        self._reset_worlds(list(range(self.n_worlds)))
        self._returns[:] = 0.0
        return self._obs.copy()

    def path_bearings(self, ahead_m: float) -> np.ndarray:
        """(n_worlds, n_robots) the bearing, in each robot's frame, of the point `ahead_m` along its free path to
        its goal now (:meth:`MultiRobotSim.path_bearing`): the map's knowledge, for a teacher, never a policy."""
        if self._local is not None:
            return self._local.path_bearings(ahead_m)
        for w in self._workers:
            w.send("bearings", ahead_m)
        return np.concatenate([w.receive() for w in self._workers])

    def others_in_frame(self) -> np.ndarray:
        """(n_worlds, n_robots, n_robots - 1, 2) the other robots' positions in each robot's frame
        (:meth:`MultiRobotSim.others_in_frame`): for a teacher, never a policy."""
        if self._local is not None:
            return self._local.others_in_frame()
        for w in self._workers:
            w.send("others", None)
        return np.concatenate([w.receive() for w in self._workers])

    def _step_all(self, actions: np.ndarray) -> _Stepped:
        if self._local is not None:
            return self._local.step(actions)
        self._send_step(actions)
        return self._receive_step()

    def _send_step(self, actions: np.ndarray) -> None:
        for w, (a, b) in zip(self._workers, self._shares, strict=True):
            w.send("step", np.asarray(actions[a:b]))

    def _receive_step(self) -> _Stepped:
        parts = [w.receive() for w in self._workers]
        return _Stepped(*(np.concatenate([getattr(p, f) for p in parts]) for f in _Stepped.__dataclass_fields__))

    def step_async(self, actions: np.ndarray) -> None:
        """Start every world's step with `actions` and return at once (worlds in worker processes only); this
        process works meanwhile, then takes the step with `step_wait`."""
        if self._local is not None:
            raise RuntimeError("step_async needs the worlds in worker processes (VecWorlds(remote=True))")
        if self._pending:
            raise RuntimeError("a step is already under way: step_wait first")
        self._send_step(actions)
        self._pending = True

    def step_wait(self) -> WorldsStep:
        """The step begun by `step_async` (as `step` returns it)."""
        if not self._pending:
            raise RuntimeError("no step under way: step_async first")
        self._pending = False
        return self._finish(self._receive_step())

    def step(self, actions: np.ndarray) -> WorldsStep:
        """Advance every world one control period; `actions` is (n_worlds, n_robots, 2) or (n_worlds, n_robots)."""
        return self._finish(self._step_all(actions))

    def _finish(self, s: _Stepped) -> WorldsStep:
        next_obs = np.asarray(s.obs, dtype=np.float32)
        act = s.active
        reward = np.where(act, s.reward, 0.0)
        self._returns += reward
        terminated = act & s.done
        truncated = act & ~terminated & s.truncated[:, None]
        ended = s.truncated | s.done.all(axis=1)
        finished: list[EpisodeRecord] = []
        for j in np.flatnonzero(ended):
            finished.append(
                EpisodeRecord(
                    world=int(j),
                    seed=int(self._episode_seed[j]),
                    steps=int(s.steps[j]),
                    returns=self._returns[j].copy(),
                    reached=s.reached[j].copy(),
                    collided=s.collided[j].copy(),
                    team_success=bool(s.team_success[j]),
                )
            )
            self._returns[j] = 0.0
        running = ~ended
        self._obs[running] = next_obs[running]
        if finished:
            self._reset_worlds([int(j) for j in np.flatnonzero(ended)])
        return WorldsStep(
            obs=self._obs.copy(),
            next_obs=next_obs,
            reward=reward,
            active=np.array(act, dtype=bool),
            terminated=terminated,
            truncated=truncated,
            world_ended=ended,
            finished=finished,
        )
