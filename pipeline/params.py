"""params.yaml sections as frozen, typed dataclasses.

Each top-level section of params.yaml maps to one class here and carries the name of the dvc
stage or library part that reads it. Loading is strict: unknown, missing, mistyped and
out-of-range keys are reported together in one ConfigError naming the file and dotted keys.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Literal

from pipeline.core import quantities as Q
from pipeline.core.actions import ActionCodec, ActionKind
from pipeline.core.judge import ProgressDistance, RewardWeights
from pipeline.core.network import StaleScan
from pipeline.core.observation import LAYOUTS, LayoutName, ObservationLayout, ObservedPose
from pipeline.core.scan import Reduction
from pipeline.core.scenario import SPARK_WHEEL_RADIUS_M, SPARK_WHEEL_SEPARATION_M
from pipeline.errors import MISSING, ConfigError, ConfigProblem
from pipeline.mappings import bounds_text, from_mapping, in_bounds, merge, read_yaml, setting, to_mapping


@dataclass(frozen=True)
class LidarConfig:
    """The policy's lidar: beam count and range limits (m), and the simulated sensor's noise."""

    beams: int = setting(15, ge=1, le=4096)
    range_min_m: float = setting(0.055, ge=0.0)
    range_max_m: float = setting(5.0, gt=0.0, le=100.0)
    noise_sigma_m: float = Q.NOISE_SIGMA_M.setting(0.01)
    dropout_prob: float = Q.DROPOUT_PROB.setting(0.0)
    bias_m: float = Q.BIAS_M.setting(0.0)
    sim_beams: int = setting(15, ge=1, le=4096)
    reduction: Reduction = setting("sector_min")
    robot_radius_seen_m: float = setting(0.0, ge=0.0, le=1.0)
    height_m: float = setting(0.1, gt=0.0)
    mount_yaw_rad: float = Q.MOUNT_YAW_RAD.setting(0.0)
    """The simulated lidar's mounting yaw: beam k of sim_beams points at 2 pi k / sim_beams + mount_yaw_rad."""
    noise_per_m: float = Q.NOISE_PER_M.setting(0.0, optional=True)
    """Range-dependent noise: a beam's sigma is noise_sigma_m + noise_per_m * range."""
    mount_xy_m: tuple[float, ...] = Q.MOUNT_XY_M.setting((0.0, 0.0), min_len=2, max_len=2, optional=True)
    """Where the beams start in the robot frame (forward, left) (m)."""
    range_step_m: float = Q.RANGE_STEP_M.setting(0.0, optional=True)
    """Ranges reported in steps of this (m; 0: continuous), as a driver reports them."""
    beam_noise_spread: float = Q.BEAM_NOISE_SPREAD.setting(0.0, optional=True)
    """Each beam's noise scaled by exp(s z - s^2) (mean square 1), drawn per robot and episode."""
    mixed_pixel_prob: float = Q.MIXED_PIXEL_PROB.setting(0.0, optional=True)
    """At a depth edge (a beam's range more than 0.1 m from the previous beam's), a return between the two surfaces."""
    no_return: Literal["inf", "zero", "max", "nan"] = setting("inf", optional=True)
    """What a beam without a return reads: +inf, 0, range_max_m or NaN (the observation reads each as nothing seen)."""
    scan_drop_prob: float = Q.SCAN_DROP_PROB.setting(0.0, optional=True)
    """Whole scans lost in the lidar's driver (before the network): the policy keeps the previous one."""

    def check(self) -> list[tuple[str, object, str]]:
        if not self.range_max_m > self.range_min_m:
            return [("range_max_m", self.range_max_m, f"a value > range_min_m ({self.range_min_m})")]
        return []


@dataclass(frozen=True)
class OdometryConfig:
    """Odometry error: about `drift_per_m` metres of position error per metre travelled."""

    drift_per_m: float = Q.DRIFT_PER_M.setting(0.03)


@dataclass(frozen=True)
class NetworkConfig:
    """The network between the robots' sensors and the policy, as the simulator plays it (a fleet has its own).

    Scans and odometry are produced at their rates, lost in bursts, delayed and jittered
    (:class:`pipeline.core.network.MessageStream`); a robot whose latest scan or odometry arrived longer ago than
    its staleness limit stands still, as on a fleet (the limits are the fleet file's defaults). The defaults are
    an ideal link: one scan and one odometry message per control step, nothing lost, nothing late.
    """

    scan_rate_hz: float = setting(0.0, ge=0.0, le=100.0, optional=True)
    """Scans per second; 0: one per control step."""
    odom_rate_hz: float = setting(0.0, ge=0.0, le=1000.0, optional=True)
    """Odometry messages per second; 0: one per control step."""
    loss_prob: float = Q.LOSS_PROB.setting(0.0, optional=True)
    """Share of messages lost (each stream, each robot)."""
    burst_len: float = Q.BURST_LEN.setting(1.0, optional=True)
    """Mean length (messages) of a run of lost messages; 1: independent losses."""
    delay_s: float = setting(0.0, ge=0.0, le=1.0, optional=True)
    """Latency of every message (s)."""
    jitter_s: float = Q.JITTER_S.setting(0.0, optional=True)
    """Spread of the latency: a half-normal extra delay of this standard deviation (s)."""
    scan_stale_s: float = setting(0.5, gt=0.0, le=10.0, optional=True)
    odom_stale_s: float = setting(0.3, gt=0.0, le=10.0, optional=True)
    stale_scan: StaleScan = setting("hold", optional=True)
    """What the policy observes of a stale robot's scan: the last one held, or no return on any beam. A fleet
    deploying the policy does the same (:func:`pipeline.core.network.observed_scans`)."""
    clock_offset_s: float = Q.CLOCK_OFFSET_S.setting(0.0, optional=True)
    """The robots' clock against the controller's (s): the stamps of the simulated sensor messages."""
    clock_drift_ppm: float = Q.CLOCK_DRIFT_PPM.setting(0.0, optional=True)
    """How fast the robots' clock runs against the controller's (parts per million): the stamps again."""

    @property
    def plays(self) -> bool:
        """Whether anything is played at all (else the sensors reach the policy at once, every control step)."""
        return bool(self.scan_rate_hz or self.odom_rate_hz or self.loss_prob or self.delay_s or self.jitter_s)


@dataclass(frozen=True)
class ActuationConfig:
    """How the simulated base follows (v, w) commands: delay, first-order lag, gains."""

    delay_s: float = Q.DELAY_S.setting(0.0)
    time_constant_s: float = Q.TIME_CONSTANT_S.setting(0.05)
    linear_gain: float = Q.LINEAR_GAIN.setting(1.0)
    angular_gain: float = Q.ANGULAR_GAIN.setting(1.0)
    yaw_rate_per_mps: float = setting(0.0, ge=-2.0, le=2.0, optional=True)
    """Yaw rate (rad/s) per m/s of forward speed: unequal wheels turn a straight command into an arc, which the
    odometry (wheel encoders read with the nominal radii) does not see."""
    deadband_radps: float = Q.DEADBAND_RADPS.setting(0.0, optional=True)
    """Wheel speeds (rad/s, from the command by the nominal wheel geometry below) under this stay at 0."""
    wheel_radius_m: float = Q.WHEEL_RADIUS_M.setting(SPARK_WHEEL_RADIUS_M, optional=True)
    wheel_separation_m: float = Q.WHEEL_SEPARATION_M.setting(SPARK_WHEEL_SEPARATION_M, optional=True)
    max_linear_mps: float | None = setting(None, gt=0.0, le=10.0, optional=True)
    """The base's speed limit: forward speeds (after the gain) beyond this are cut to it; None: no limit."""
    max_angular_radps: float | None = setting(None, gt=0.0, le=50.0, optional=True)
    """The same for the yaw rate."""


Range = tuple[float, ...]
"""A [low, high] range for per-episode draws; [] leaves the key at its world value."""


@dataclass(frozen=True)
class LidarRanges:
    noise_sigma_m: Range = setting((), max_len=2, optional=True)
    noise_per_m: Range = setting((), max_len=2, optional=True)
    dropout_prob: Range = setting((), max_len=2, optional=True)
    bias_m: Range = setting((), max_len=2, optional=True)
    mount_yaw_rad: Range = setting((), max_len=2, optional=True)


@dataclass(frozen=True)
class ActuationRanges:
    delay_s: Range = setting((), max_len=2, optional=True)
    time_constant_s: Range = setting((), max_len=2, optional=True)
    linear_gain: Range = setting((), max_len=2, optional=True)
    angular_gain: Range = setting((), max_len=2, optional=True)
    yaw_rate_per_mps: Range = setting((), max_len=2, optional=True)
    deadband_radps: Range = setting((), max_len=2, optional=True)


@dataclass(frozen=True)
class OdometryRanges:
    drift_per_m: Range = setting((), max_len=2, optional=True)


@dataclass(frozen=True)
class NetworkRanges:
    scan_rate_hz: Range = setting((), max_len=2, optional=True)
    odom_rate_hz: Range = setting((), max_len=2, optional=True)
    loss_prob: Range = setting((), max_len=2, optional=True)
    burst_len: Range = setting((), max_len=2, optional=True)
    delay_s: Range = setting((), max_len=2, optional=True)
    jitter_s: Range = setting((), max_len=2, optional=True)


@dataclass(frozen=True)
class RandomizeConfig:
    """Domain randomization: per episode, each key with a [low, high] range is drawn uniformly from it.

    Keys name the world's own settings (``lidar.noise_sigma_m`` is ``world.lidar.noise_sigma_m``);
    a key left out or ``[]`` keeps its world value, so each range is its own off switch.
    """

    lidar: LidarRanges = setting(LidarRanges(), optional=True)
    actuation: ActuationRanges = setting(ActuationRanges(), optional=True)
    odometry: OdometryRanges = setting(OdometryRanges(), optional=True)
    network: NetworkRanges = setting(NetworkRanges(), optional=True)

    def entries(self) -> list[tuple[str, Range]]:
        """(dotted world key, range as given) of every key, in a fixed order."""
        return [
            (f"{group.name}.{f.name}", getattr(getattr(self, group.name), f.name))
            for group in fields(self)
            for f in fields(getattr(self, group.name))
        ]

    def ranges(self) -> dict[str, tuple[float, float]]:
        """Dotted world key -> (low, high) of every range that is on, in a fixed order."""
        return {key: (float(v[0]), float(v[1])) for key, v in self.entries() if len(v) == 2}

    def check(self) -> list[tuple[str, object, str]]:
        bad: list[tuple[str, object, str]] = []
        for key, value in self.entries():
            if len(value) == 1:
                bad.append((key, list(value), "[low, high] or [] (off)"))
            elif len(value) == 2 and not value[0] <= value[1]:
                bad.append((key, list(value), "[low, high] with low <= high"))
        return bad


@dataclass(frozen=True)
class ActionConfig:
    """Action space: continuous (v, w) scaled to the limits or a discrete named set."""

    kind: ActionKind = setting("continuous")
    v_max_mps: float = setting(0.4, gt=0.0, le=5.0)
    w_max_radps: float = setting(0.2, gt=0.0, le=10.0)
    discrete_set: tuple[Literal["forward", "left", "right", "backward", "stop"], ...] = setting(
        ("forward", "left", "right"), min_len=2
    )
    reverse: bool = setting(True, optional=True)
    """Continuous actions: speed commands in [-v_max, v_max] (true) or forward only, [0, v_max] (false)."""

    def codec(self) -> ActionCodec:
        return ActionCodec(self.kind, self.v_max_mps, self.w_max_radps, tuple(self.discrete_set), reverse=self.reverse)


@dataclass(frozen=True)
class WorldConfig:
    """The simulated world: scenario, timing, sensors, actions and reward (params.yaml `world`)."""

    scenario: str = setting("obstacles")
    n_robots: int = setting(0, ge=0, le=64)
    control_period_s: float = setting(0.1, gt=0.0, le=1.0)
    physics_timestep_s: float = setting(0.005, gt=0.0, le=0.05)
    max_steps: int = setting(350, ge=1, le=100_000)
    collision_margin_m: float = setting(0.02, ge=0.0, le=0.5)
    progress_distance: ProgressDistance = setting("geodesic")
    """Progress toward the goal is measured along the free path (geodesic) or in a straight line."""
    observation: LayoutName = setting("paper")
    observed_pose: ObservedPose = setting("odometry", optional=True)
    """The pose the observation is built from: the robots' wheel odometry (the paper's), or ground truth (a
    localized robot: motion capture on a fleet, the simulator's truth)."""
    layouts: Literal["random", "fixed"] = setting("random", optional=True)
    """random: a scenario with layouts ranges draws each episode's layout from them; fixed: its own layout."""
    lidar: LidarConfig = setting(LidarConfig())
    odometry: OdometryConfig = setting(OdometryConfig())
    actuation: ActuationConfig = setting(ActuationConfig())
    network: NetworkConfig = setting(NetworkConfig(), optional=True)
    actions: ActionConfig = setting(ActionConfig())
    reward: RewardWeights = setting(RewardWeights())
    randomize: RandomizeConfig = setting(RandomizeConfig(), optional=True)

    def check(self) -> list[tuple[str, object, str]]:
        bad = self._randomized_bounds()
        ratio = self.control_period_s / self.physics_timestep_s
        if abs(ratio - round(ratio)) > 1e-9 * ratio:
            bad.append(
                (
                    "physics_timestep_s",
                    self.physics_timestep_s,
                    f"a value that divides control_period_s ({self.control_period_s}) evenly",
                )
            )
        return bad

    def _randomized_bounds(self) -> list[tuple[str, object, str]]:
        """Ranges that reach outside the bounds of the key they draw."""
        bad: list[tuple[str, object, str]] = []
        for key, (low, high) in self.randomize.ranges().items():
            group, name = key.split(".")
            meta = next(f for f in fields(getattr(self, group)) if f.name == name).metadata
            if not (in_bounds(low, meta) and in_bounds(high, meta)):
                bad.append((f"randomize.{key}", [low, high], f"a range inside the key's bounds ({bounds_text(meta)})"))
        return bad

    def with_values(self, values: dict[str, float]) -> WorldConfig:
        """This world with dotted keys (``actuation.delay_s``) set to `values` (the draws of one episode)."""
        groups: dict[str, dict[str, float]] = {}
        for key, value in values.items():
            group, name = key.split(".")
            groups.setdefault(group, {})[name] = value
        return replace(self, **{g: replace(getattr(self, g), **kv) for g, kv in groups.items()})

    @property
    def substeps(self) -> int:
        """Physics steps per control step."""
        return round(self.control_period_s / self.physics_timestep_s)

    @property
    def delay_substeps(self) -> int:
        """Actuation delay in physics steps (rounded)."""
        return math.floor(self.actuation.delay_s / self.physics_timestep_s + 0.5)

    def layout(self) -> ObservationLayout:
        return ObservationLayout(self.observation, self.lidar.beams)

    def codec(self) -> ActionCodec:
        return self.actions.codec()


Algorithm = Literal["sac", "dqn", "ppo"]
Teacher = Literal["scripted", "path"]
Mode = Literal["independent", "shared", "centralized"]


@dataclass(frozen=True)
class SacConfig:
    """SAC settings (continuous actions)."""

    tau: float = setting(0.005, gt=0.0, le=1.0)
    ent_coef: float = setting(0.0, ge=0.0, le=10.0)
    """Entropy coefficient; 0 learns it automatically toward the target entropy."""
    ent_coef_init: float = setting(1.0, gt=0.0, le=10.0, optional=True)
    """Where the learned entropy coefficient starts (SB3's default 1.0); with `ent_coef` 0 only."""
    target_entropy_scale: float = setting(1.0, gt=0.0, le=10.0)
    """Target entropy is -scale * action dimensions (SAC's default is scale 1)."""
    update: Literal["batched", "library"] = setting("batched", optional=True)
    """How gradient steps run: `batched` steps every learner's networks in one batched pass
    (pipeline/learn/sac/batched.py), `library` calls stable-baselines3's SAC.train per learner."""


@dataclass(frozen=True)
class DqnConfig:
    """DQN settings (discrete actions): dueling head, prioritized replay, double-Q target."""

    dueling: bool = setting(True)
    prioritized: bool = setting(True)
    double_q: bool = setting(True)
    per_alpha: float = setting(0.6, ge=0.0, le=1.0)
    per_beta0: float = setting(0.4, ge=0.0, le=1.0)
    per_epsilon: float = setting(1e-6, gt=0.0, le=1.0)
    exploration_fraction: float = setting(0.3, gt=0.0, le=1.0)
    exploration_initial_eps: float = setting(1.0, ge=0.0, le=1.0)
    exploration_final_eps: float = setting(0.05, ge=0.0, le=1.0)
    target_update_interval: int = setting(2000, ge=1)
    """Transitions between copies of the online network into the target network."""
    max_grad_norm: float = setting(10.0, gt=0.0)


@dataclass(frozen=True)
class PpoConfig:
    """PPO settings (either action kind)."""

    n_steps: int = setting(256, ge=2, le=100_000)
    """World steps per rollout (each stream contributes n_steps samples)."""
    n_epochs: int = setting(10, ge=1, le=100)
    minibatch_size: int = setting(256, ge=2)
    gae_lambda: float = setting(0.95, ge=0.0, le=1.0)
    clip_range: float = setting(0.2, gt=0.0, le=1.0)
    ent_coef: float = setting(0.0, ge=0.0, le=1.0)
    vf_coef: float = setting(0.5, gt=0.0, le=10.0)
    max_grad_norm: float = setting(0.5, gt=0.0)


@dataclass(frozen=True)
class ConvergenceConfig:
    """The convergence criterion: every robot's success over the last `window_episodes` above `success_threshold`."""

    window_episodes: int = setting(20, ge=1, le=10_000)
    success_threshold: float = setting(0.8, ge=0.0, lt=1.0)
    stop: bool = setting(False)
    """Stop training at convergence (else train the whole budget)."""


@dataclass(frozen=True)
class SelectionConfig:
    """Which weights training hands to export. Every `every_steps` world steps (0: never) the current
    policy drives `episodes` deterministic episodes from the exact starts (seeds `seed`, `seed` + 1, ...,
    apart from eval_sim's); `keep: best` exports the weights with the highest robot success there
    (ties: team success, then the later), `keep: last` the final weights."""

    keep: Literal["best", "last"] = setting("last")
    every_steps: int = setting(0, ge=0, le=100_000_000)
    episodes: int = setting(20, ge=1, le=10_000)
    seed: int = setting(5_000, ge=0)
    stop_at_success: float | None = setting(None, gt=0.0, le=1.0, optional=True)
    """Stop training once an evaluation reaches this robot success (None: train the whole budget)."""
    stop_after_convergence: bool = setting(False)
    """With `stop_at_success`: stop only at an evaluation after the convergence criterion has held on the training
    episodes. A greedy policy can be perfect while the exploring robots still miss; stopping there leaves the
    criterion unmeasured and the run counts as not converged."""

    def check(self) -> list[tuple[str, object, str]]:
        if self.keep == "best" and self.every_steps == 0:
            return [("every_steps", 0, "> 0 with keep 'best' (the best needs evaluations)")]
        if self.stop_at_success is not None and self.every_steps == 0:
            return [("every_steps", 0, "> 0 with stop_at_success (stopping needs evaluations)")]
        if self.stop_after_convergence and self.stop_at_success is None:
            return [("stop_after_convergence", True, "false without stop_at_success (it qualifies that stop)")]
        return []


@dataclass(frozen=True)
class ImitationConfig:
    """A warm start for PPO (pipeline/learn/imitation.py): before reinforcement learning the policy imitates the
    scripted go-to-goal controller in the training worlds, and its value head learns the controller's returns."""

    steps: int = setting(0, ge=0, le=100_000_000)
    """World steps of the controller's driving to learn from, summed over the parallel worlds (0: off). They are
    not counted in `total_steps`; train_metrics.json reports them as train/imitation_world_steps."""
    epochs: int = setting(20, ge=1, le=1000)
    """Passes over the controller's samples."""
    log_std: float = setting(-1.0, ge=-5.0, le=1.0)
    """The log standard deviation of the policy's action noise afterwards (actions in [-1, 1]; continuous)."""
    rounds: int = setting(1, ge=1, le=20, optional=True)
    """Rounds of demonstration (each `steps` world steps): the controller drives the first; in each further one
    the policy fitted so far drives and the controller's actions where it goes are the labels (DAgger)."""
    teacher: Teacher = setting("scripted", optional=True)
    """The controller imitated: ``scripted`` (go-to-goal, sees what the policy sees) or ``path`` (also told where
    each robot's free path through the episode's map leads; continuous actions only)."""
    memory_dropout: float = setting(0.0, ge=0.0, lt=1.0, optional=True)
    """With ``world.observation: rich_memory``: the share of samples, drawn afresh in every minibatch of the
    fits, whose previous command is shown as zero (a robot at rest), so that the student cannot learn to only
    repeat it (0: off)."""


@dataclass(frozen=True)
class TrainConfig:
    """The `train` stage: algorithm, multi-agent mode, budget and hyperparameters."""

    algorithm: Algorithm = setting("sac")
    mode: Mode = setting("independent")
    total_steps: int = setting(200_000, ge=0, le=100_000_000)
    """World control steps summed over the parallel worlds; 0 with `imitation.steps` > 0: the imitated policy
    alone (evaluated, checkpointed and exported as it is, no reinforcement learning)."""
    n_envs: int = setting(4, ge=1, le=256)
    """Parallel worlds stepped in lockstep."""
    world_workers: int = setting(1, ge=1, le=256)
    """Processes that step the worlds (1: the trainer's own); the transitions are the same whatever the number."""
    start_xy_m: float = setting(0.3, ge=0.0, le=5.0)
    """Training episodes start each robot up to this far (uniformly, in x and y) from its start."""
    start_yaw_rad: float = setting(0.6, ge=0.0, le=3.1416)
    """... and turned up to this much; evaluation and deployment always use the exact starts."""
    seed: int = setting(0, ge=0)
    net_arch: tuple[int, ...] = setting((256, 256), min_len=1)
    observation_scaling: Literal["none", "bounds"] = setting("none")
    """bounds: the network maps each observation value from its bounds to [-1, 1] first (ppo)."""
    learning_rate: float = setting(3e-4, gt=0.0, le=1.0)
    learning_rate_schedule: Literal["constant", "linear"] = setting("constant")
    """linear: decay to 0 over the budget, which steadies the final policy."""
    gamma: float = setting(0.99, gt=0.0, le=1.0)
    batch_size: int = setting(256, ge=1)
    buffer_size: int = setting(300_000, ge=1)
    learning_starts: int = setting(5_000, ge=0)
    """Transitions per learner collected with random actions before updates start (off-policy)."""
    updates_per_transition: float = setting(0.5, gt=0.0, le=64.0)
    """Gradient steps per stored transition (off-policy)."""
    train_every_steps: int = setting(4, ge=1)
    """World steps between update rounds (off-policy)."""
    share_experience: bool = setting(False, optional=True)
    """independent mode, sac and dqn: every robot's network also stores the other robots' transitions in its replay
    (its own network and its own gradient steps: as many as without them, one per own transition times
    `updates_per_transition`)."""
    n_step: int = setting(1, ge=1, le=20, optional=True)
    """sac and dqn: each stored transition spans this many steps of its robot (the discounted rewards summed, the
    bootstrap at gamma^n_step, a window that reaches a terminal step ending there); 1: one-step transitions."""
    overlap: bool = setting(False, optional=True)
    """sac and dqn: the worlds step in a process of their own while the learners take their gradient steps
    (collection and learning overlapped on two cores). Each round of gradient steps then sees the transitions up to
    the step before the one being collected: the behaviour policy lags the learner by one update, which off-policy
    learning from a replay takes as it takes any older data. Deterministic: the same seed gives the same weights."""
    checkpoint_every_episodes: int = setting(100, ge=1)
    torch_threads: int = setting(1, ge=1, le=64)
    sac: SacConfig = setting(SacConfig())
    dqn: DqnConfig = setting(DqnConfig())
    ppo: PpoConfig = setting(PpoConfig())
    convergence: ConvergenceConfig = setting(ConvergenceConfig())
    selection: SelectionConfig = setting(SelectionConfig())
    imitation: ImitationConfig = setting(ImitationConfig(), optional=True)
    out_dir: str = setting("models")

    def check(self) -> list[tuple[str, object, str]]:
        bad: list[tuple[str, object, str]] = []
        if any(width < 1 for width in self.net_arch):
            bad.append(("net_arch", list(self.net_arch), "layer widths >= 1"))
        if self.observation_scaling != "none" and self.algorithm != "ppo":
            bad.append(("observation_scaling", self.observation_scaling, f"'none' with algorithm {self.algorithm}"))
        if self.imitation.steps > 0 and self.algorithm != "ppo":
            bad.append(("imitation.steps", self.imitation.steps, f"0 with algorithm {self.algorithm} (ppo only)"))
        if self.share_experience and (self.mode != "independent" or self.algorithm == "ppo"):
            bad.append(("share_experience", True, f"false with mode {self.mode} and algorithm {self.algorithm} "
                        "(independent sac or dqn only)"))  # fmt: skip
        if self.n_step > 1 and self.algorithm == "ppo":
            bad.append(("n_step", self.n_step, "1 with algorithm ppo (n-step transitions are for sac and dqn)"))
        if self.overlap and self.algorithm == "ppo":
            bad.append(("overlap", True, f"false with algorithm ppo in mode {self.mode} (its updates come between "
                        "rollouts, with the worlds idle by design: nothing to overlap; sac and dqn only)"))  # fmt: skip
        if self.total_steps == 0 and self.imitation.steps == 0:
            bad.append(("total_steps", 0, ">= 1, or 0 with imitation.steps > 0 (the imitated policy alone)"))
        return bad


@dataclass(frozen=True)
class ExportConfig:
    """The `export` stage: ONNX policy files from the trained weights."""

    golden_observations: int = setting(64, ge=1, le=100_000)
    """Observations (drawn from the simulated world) on which ONNX must equal torch."""
    tolerance: float = setting(1e-3, gt=0.0, le=1e-2)
    """Largest allowed difference of the ONNX graph's continuous commands from torch's, as a share of each robot's
    limit on each channel (after decoding: what reaches a robot)."""
    opset: int = setting(17, ge=13, le=23)
    out_dir: str = setting("models")


@dataclass(frozen=True)
class EvalSimConfig:
    """The `eval_sim` stage: episodes of the exported policy in the simulated world, recorded to MCAP."""

    episodes: int = setting(200, ge=1, le=1_000_000)
    seed: int = setting(10_000, ge=0)
    record: bool = setting(True)
    chunk_size_bytes: int = setting(1_048_576, ge=1024)
    out_dir: str = setting("logs/sim")
    randomized: bool = setting(False, optional=True)
    """false: every episode at the round world's values (for the calibrated round, the simulator's prediction of
    the reality it was calibrated to); true: each episode under its own draw of `world.randomize`, as in training."""
    live: bool = setting(False)
    """Serve the session to the Foxglove app while it runs (a WebSocket server on `live_port`)."""
    live_port: int = setting(8765, ge=0, le=65535)
    """Port of the live view's server (0: any free port; 8765 is the app's default)."""


@dataclass(frozen=True)
class ScriptedEvalConfig:
    """The `scripted_eval` stage: episodes of the scripted controller in the simulated world."""

    episodes: int = setting(20, ge=1, le=100_000)
    seed: int = setting(0, ge=0)
    out_dir: str = setting("logs/scripted")


@dataclass(frozen=True)
class DeployConfig:
    """The `deploy` stage: episodes of the round's exported policy on the fleet, recorded to MCAP."""

    fleet: str = setting("twin")
    """A bundled fleet (twin, twin_ros1, twin_rclpy, spark_lab) or the path of a fleet YAML file."""
    episodes: int = setting(50, ge=1, le=100_000)
    seed: int = setting(20_000, ge=0)
    time_scale: float | Literal["auto"] = setting(0.0, ge=0.0, le=20.0)
    """The twin's time scale (``auto``: the highest the host lets it keep, :mod:`pipeline.rollout.pace`); 0 keeps
    the fleet file's."""
    profile: str = setting("", allow_empty=True)
    """The twin's reality profile; empty keeps the fleet file's."""
    chunk_size_bytes: int = setting(1_048_576, ge=1024)
    out_dir: str = setting("logs/real")
    live: bool = setting(False)
    """Serve the session to the Foxglove app while it runs (a WebSocket server on `live_port`)."""
    live_port: int = setting(8765, ge=0, le=65535)
    """Port of the live view's server (0: any free port; 8765 is the app's default)."""


@dataclass(frozen=True)
class CalibrateConfig:
    """The `calibrate` stage: estimate the simulator's noise and actuation from a deployment recording."""

    round: Literal["nominal"] = setting("nominal")
    """The round whose deployment recording is calibrated from."""
    parts: tuple[Literal["lidar", "actuation", "odometry", "network"], ...] = setting(
        ("lidar", "actuation", "odometry", "network"), min_len=1
    )
    """The groups of the reality profile to estimate."""
    stationary_min_s: float = setting(1.0, gt=0.0, le=60.0)
    """Lidar noise is measured on spans where a robot stands still at least this long."""
    bootstrap: int = setting(200, ge=20, le=100_000)
    seed: int = setting(0, ge=0)
    out_dir: str = setting("logs/calibration")


@dataclass(frozen=True)
class ReplayConfig:
    """The `replay` stage: the policy on recorded observations, and recorded commands open loop in sim."""

    horizon_s: float = setting(10.0, gt=0.0, le=600.0)
    max_episodes: int = setting(20, ge=1, le=10_000)
    tolerance: float = setting(1e-5, gt=0.0, le=1.0)
    """Largest |replayed - recorded| policy output counted as agreement."""
    out_dir: str = setting("logs/replay")


@dataclass(frozen=True)
class ReportConfig:
    """The `report` stage: sim vs real before and after calibration, as report.md, metrics.json and plots."""

    trajectory_episodes: int = setting(3, ge=1, le=20)
    out_dir: str = setting("logs/report")


@dataclass(frozen=True)
class FleetCheckConfig:
    """The `fleet_check` stage: before any training, the deploy fleet's pinned DDS domain is not held by another
    deployment on this machine."""

    out: str = setting("logs/fleet_check.json")


@dataclass(frozen=True)
class Params:
    """All of params.yaml."""

    world: WorldConfig = setting()
    fleet_check: FleetCheckConfig = setting()
    scripted_eval: ScriptedEvalConfig = setting()
    train: TrainConfig = setting()
    export: ExportConfig = setting()
    eval_sim: EvalSimConfig = setting()
    deploy: DeployConfig = setting()
    calibrate: CalibrateConfig = setting()
    replay: ReplayConfig = setting()
    report: ReportConfig = setting()

    def check(self) -> list[tuple[str, object, str]]:
        return check_training_fits_world(self.train, self.world)


def load_params(path: str | Path = "params.yaml") -> Params:
    """Read and validate params.yaml; raises ConfigError naming every bad key."""
    return from_mapping(Params, read_yaml(path), str(path))


def world_config(
    overrides: dict[str, Any] | None = None, base: WorldConfig | None = None, source: str = "<overrides>"
) -> WorldConfig:
    """A WorldConfig from `base` (defaults if None) with nested `overrides` merged in and validated."""
    data = to_mapping(base if base is not None else WorldConfig())
    return from_mapping(WorldConfig, merge(data, overrides or {}), source)


_GOAL_LAYOUTS = " or ".join(", ".join(repr(n) for n in LAYOUTS if n != "paper").rsplit(", ", 1))
"""The observation layouts that carry the goal (every one but the paper's), as an error's allowed values."""


def check_training_fits_world(train: TrainConfig, world: WorldConfig) -> list[tuple[str, object, str]]:
    """Problems (dotted key, value, allowed) where the algorithm or mode does not fit the world."""
    bad: list[tuple[str, object, str]] = []
    kind = world.actions.kind
    if train.algorithm == "sac" and kind != "continuous":
        bad.append(("world.actions.kind", kind, "'continuous' for train.algorithm 'sac'"))
    if train.algorithm == "dqn" and kind != "discrete":
        bad.append(("world.actions.kind", kind, "'discrete' for train.algorithm 'dqn'"))
    if train.imitation.steps > 0 and world.observation == "paper":
        bad.append(
            (
                "world.observation",
                world.observation,
                f"{_GOAL_LAYOUTS} with train.imitation.steps > 0 (the teacher steers by it)",
            )
        )
    if train.imitation.steps > 0 and train.imitation.teacher == "path" and kind != "continuous":
        bad.append(
            ("world.actions.kind", kind, "'continuous' with train.imitation.teacher 'path' (it drives in reverse)")
        )
    if train.imitation.memory_dropout > 0 and world.observation != "rich_memory":
        bad.append(
            (
                "train.imitation.memory_dropout",
                train.imitation.memory_dropout,
                f"0 with world.observation {world.observation!r} ('rich_memory' only: it drops the previous command)",
            )
        )
    if train.mode == "shared" and world.observation == "paper":
        bad.append(
            (
                "world.observation",
                world.observation,
                f"{_GOAL_LAYOUTS} for train.mode 'shared' (one network must tell robots apart by their goal)",
            )
        )
    return bad


def round_world(params: Params, round_name: str, source: str = "params.yaml") -> WorldConfig:
    """The simulated world of a round of the loop: `nominal` is params.yaml's world; `calibrated`
    adds the calibration file's estimates on top of it."""
    if round_name == "nominal":
        return params.world
    if round_name == "calibrated":
        return calibrated_world(params.world, Path(params.calibrate.out_dir) / CALIBRATION_FILE)
    raise ConfigError(source, [ConfigProblem("--round", round_name, "one of 'nominal', 'calibrated'")])


def evaluation_world(params: Params, round_name: str, source: str = "params.yaml") -> WorldConfig:
    """The world `eval_sim` runs a round in: the round's world at its values (the calibrated round: at the
    estimates, the simulator's prediction of the reality it was calibrated to), or under its training
    randomization where ``eval_sim.randomized`` asks for it."""
    world = round_world(params, round_name, source)
    return world if params.eval_sim.randomized else replace(world, randomize=RandomizeConfig())


CALIBRATION_FILE = "calibration.yaml"
CALIBRATION_FORMAT = "mrl-calibration/1"
"""The format tag of calibration.yaml (written by :mod:`pipeline.calibration.output`, read by
:func:`read_calibration_file`)."""


@dataclass(frozen=True)
class CalibratedKey:
    """One estimated key of calibration.yaml's ``uncertainty``: ``ok`` with its value, standard error and 95 %
    interval (None where the value is exact, e.g. a beam count), or why it could not be identified."""

    key: str
    status: str
    value: float | None
    interval_95: tuple[float, float] | None
    unit: str
    reason: str

    @property
    def ok(self) -> bool:
        """Identified (``ok``, or ``weak``: an interval wider than the value)."""
        return self.status in ("ok", "weak")


@dataclass(frozen=True)
class CalibrationFile:
    """calibration.yaml, read and checked: the world overrides training applies, the estimates in the reality
    profile's keys, each estimated key with its interval, what was left unidentified and why, and the sources."""

    path: str
    scenario: str
    world: dict[str, Any]
    profile: dict[str, Any]
    keys: dict[str, CalibratedKey]
    """By dotted profile key (``lidar.rate_hz``, ``map.box_offsets_m[1][1]``)."""
    unidentified: dict[str, str]
    speed_limits: dict[str, Any]
    source: dict[str, Any]
    effective: dict[str, Any] = field(default_factory=dict)
    """Values of the simulator's model that stand for several profile keys together, with those keys and the model."""
    ambiguous: tuple[dict[str, Any], ...] = ()
    """Where two drive models explained the recording alike: the readings, the one kept, what would separate them."""


def _calibrated_keys(uncertainty: Any) -> tuple[dict[str, CalibratedKey], list[ConfigProblem]]:
    keys: dict[str, CalibratedKey] = {}
    problems: list[ConfigProblem] = []
    if not isinstance(uncertainty, dict):
        return keys, [ConfigProblem("uncertainty", uncertainty, "a mapping of groups of estimated keys")]
    for group, entries in uncertainty.items():
        for name, entry in (entries or {}).items() if isinstance(entries, dict) else ():
            key = f"{group}.{name}"
            if not isinstance(entry, dict) or entry.get("status") not in ("ok", "weak", "unidentifiable"):
                problems.append(
                    ConfigProblem(f"uncertainty.{key}", entry, "a mapping with status ok, weak or unidentifiable")
                )
                continue
            interval = entry.get("interval_95")
            value = entry.get("value")
            if entry["status"] in ("ok", "weak") and not (
                isinstance(value, (int, float))
                and (interval is None or (isinstance(interval, list) and len(interval) == 2))
            ):
                problems.append(
                    ConfigProblem(f"uncertainty.{key}", entry, "a value and a two-number interval_95 or null")
                )
                continue
            keys[key] = CalibratedKey(
                key=key,
                status=str(entry["status"]),
                value=None if value is None else float(value),
                interval_95=None if not interval else (float(interval[0]), float(interval[1])),
                unit=str(entry.get("unit", "")),
                reason=str(entry.get("reason", "")),
            )
        if not isinstance(entries, dict):
            problems.append(ConfigProblem(f"uncertainty.{group}", entries, "a mapping of estimated keys"))
    return keys, problems


def read_calibration_file(path: str | Path) -> CalibrationFile:
    """Read calibration.yaml; ConfigError naming the file and each bad key (another format tag included)."""
    data = read_yaml(path)
    where = str(path)
    if not isinstance(data, dict):
        raise ConfigError(where, [ConfigProblem("<top>", data, "a mapping (the calibrate stage writes it)")])
    if data.get("format") != CALIBRATION_FORMAT:
        raise ConfigError(
            where,
            [
                ConfigProblem(
                    "format",
                    data.get("format", MISSING),
                    f"{CALIBRATION_FORMAT!r}: calibrate again (dvc repro calibrate, or mrl calibrate BAG --out DIR)",
                )
            ],
        )
    problems: list[ConfigProblem] = []
    for key in ("world", "profile", "unidentified", "speed_limits", "source", "effective"):
        if not isinstance(data.get(key, {}), dict):
            problems.append(ConfigProblem(key, data.get(key), "a mapping (the calibrate stage writes it)"))
    if "world" not in data:
        problems.append(ConfigProblem("world", MISSING, "a mapping of world settings (the calibrate stage writes it)"))
    keys, bad_keys = _calibrated_keys(data.get("uncertainty", {}))
    problems += bad_keys
    if problems:
        raise ConfigError(where, problems)
    return CalibrationFile(
        path=where,
        scenario=str(data.get("scenario", "")),
        world=dict(data["world"]),
        profile=dict(data.get("profile") or {}),
        keys=keys,
        unidentified={str(k): str(v) for k, v in (data.get("unidentified") or {}).items()},
        speed_limits=dict(data.get("speed_limits") or {}),
        source=dict(data.get("source") or {}),
        effective=dict(data.get("effective") or {}),
        ambiguous=tuple(a for a in (data.get("ambiguous") or []) if isinstance(a, dict)),
    )


def calibrated_world(base: WorldConfig, path: Path) -> WorldConfig:
    """`base` with the ``world`` overrides of a calibration file (written by the calibrate stage)."""
    return world_config(read_calibration_file(path).world, base=base, source=str(path))
