"""A warm start for PPO (`train.imitation`): before reinforcement learning, the policy imitates a scripted
controller in the training worlds: `teacher` ``scripted``, the go-to-goal controller
(:class:`pipeline.policy.scripted.GoToGoalController`, which sees what the policy sees), or ``path``, the
path-following controller (:class:`pipeline.policy.scripted.PathFollowingController`), which is also told
where each robot's free path through the episode's map leads; the policy learns from the lidar alone what
that knowledge made the teacher do.

The controller drives `steps` world steps of training episodes (their layout draws, randomization and start
perturbations); every learner then fits, on what its streams saw, its action head to the controller's
actions (squared error on the Gaussian mean for continuous actions, cross-entropy on the logits for
discrete ones) and its value head to the controller's discounted returns, for `epochs` passes in
minibatches of ``ppo.minibatch_size``. Only samples whose episode ended within the demonstration count: a
return cut off by the end of the demonstration would be biased.

With `rounds` > 1 the demonstration goes on as DAgger does: in each further round the policy fitted so far
drives `steps` more world steps (its action means), the controller's actions in the states the policy itself
reaches are recorded as the labels, and the policy is fitted again on every round's samples (its value head
to the returns of whoever drove). A student of a plain demonstration has never seen the states its own
mistakes lead to; these rounds show it what the teacher does there.

With ``world.observation: rich_memory`` the student sees the command it was given a step before, and a
teacher's commands change little from one step to the next: repeating the previous one fits most samples,
and a student that learned only that stays at rest once it stops (the copycat failure). `memory_dropout`
shows that command as zero (a robot at rest) in a random share of every minibatch's samples, so that at rest,
too, the action must come from what the robot sees.

Afterwards the policy's action noise is set to ``exp(log_std)``, and PPO goes on from these weights with its
own optimizer state, untouched here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch as th
from stable_baselines3 import PPO
from torch.nn import functional as F
from tqdm import tqdm

from pipeline.learn.common.modes import StreamMap
from pipeline.learn.common.worlds import VecWorlds
from pipeline.params import Teacher, TrainConfig
from pipeline.policy.scripted import GoToGoalController, PathFollowingController


@dataclass(frozen=True)
class Demonstration:
    """One learner's samples of the controller's driving: observations, actions (the learner's own action
    space), discounted returns; only samples of episodes that ended within the demonstration."""

    obs: np.ndarray
    actions: np.ndarray
    returns: np.ndarray


@dataclass(frozen=True)
class ImitationResult:
    world_steps: int
    samples: int
    episodes: int
    rounds: int
    action_loss: float
    """Per learner mean, over the last epoch: squared error of the action mean (continuous) or cross-entropy."""
    value_loss: float


def demonstrate(
    worlds: VecWorlds,
    streams: StreamMap,
    world_steps: int,
    gamma: float,
    progress: bool = False,
    teacher: Teacher = "scripted",
    driver: Callable[[list[np.ndarray]], list[np.ndarray]] | None = None,
) -> tuple[list[Demonstration], int, int]:
    """The `teacher` controller drives every world for `world_steps` world steps (summed over the worlds, as
    training counts them); per learner its streams' samples with the controller's returns, the world steps
    driven and the episodes finished. With a `driver` (per learner observations to per learner actions) the
    driver steers the worlds and the teacher's actions are only recorded, with the driver's returns."""
    controller: Callable[[np.ndarray], np.ndarray]
    if teacher == "path":
        follower = PathFollowingController(worlds.config.layout(), worlds.codec)

        def controller(flat_obs: np.ndarray) -> np.ndarray:
            others = worlds.others_in_frame()
            return follower(
                flat_obs, worlds.path_bearings(follower.ahead_m).reshape(-1), others.reshape(-1, *others.shape[2:])
            )
    else:
        controller = GoToGoalController(worlds.config.layout(), worlds.codec)

    obs = worlds.reset()
    n_learners = streams.n_learners
    seen: list[list[np.ndarray]] = [[] for _ in range(n_learners)]
    acts: list[list[np.ndarray]] = [[] for _ in range(n_learners)]
    rewards: list[list[np.ndarray]] = [[] for _ in range(n_learners)]
    valid: list[list[np.ndarray]] = [[] for _ in range(n_learners)]
    ends: list[list[np.ndarray]] = [[] for _ in range(n_learners)]
    steps = episodes = 0
    desc = "imitation: controller drives" if driver is None else "imitation: policy drives, controller labels"
    bar = tqdm(total=world_steps, desc=desc, unit="step", disable=not progress)
    while steps < world_steps:
        world_actions = controller(obs.reshape(-1, streams.obs_size))
        world_actions = world_actions.reshape(streams.n_worlds, streams.n_robots, *world_actions.shape[1:])
        per_learner = streams.learner_obs(obs)
        step = worlds.step(world_actions if driver is None else streams.world_actions(driver(per_learner)))
        for i, (o, a, b) in enumerate(
            zip(per_learner, streams.learner_actions(world_actions), streams.learner_batches(step), strict=True)
        ):
            seen[i].append(o)
            acts[i].append(a)
            rewards[i].append(b.reward)
            valid[i].append(b.active)
            ends[i].append(b.terminated | b.truncated)
        steps += worlds.n_worlds
        episodes += len(step.finished)
        obs = step.obs
        bar.update(worlds.n_worlds)
    bar.close()
    out = []
    for i in range(n_learners):
        r, ok, end = np.stack(rewards[i]), np.stack(valid[i]), np.stack(ends[i])
        returns, known = discounted_returns(r, ok, end, gamma)
        keep = ok & known
        out.append(
            Demonstration(
                obs=np.concatenate(seen[i])[keep.reshape(-1)],
                actions=np.concatenate(acts[i])[keep.reshape(-1)],
                returns=returns[keep].astype(np.float32),
            )
        )
    return out, steps, episodes


def discounted_returns(
    reward: np.ndarray, active: np.ndarray, ended: np.ndarray, gamma: float
) -> tuple[np.ndarray, np.ndarray]:
    """Per (step, stream): the discounted return from that step to its episode's end, and whether that end
    lies within the arrays (else the return is cut off and unknown). Arrays are (steps, streams); a stream
    inactive at a step (a robot that already finished) has no sample there."""
    n_steps = reward.shape[0]
    returns = np.zeros(reward.shape, dtype=np.float64)
    known = np.zeros(reward.shape, dtype=bool)
    g = np.zeros(reward.shape[1])
    k = np.zeros(reward.shape[1], dtype=bool)
    for t in range(n_steps - 1, -1, -1):
        g = np.where(ended[t], reward[t], reward[t] + gamma * g)
        k = ended[t] | k
        g = np.where(active[t], g, 0.0)
        returns[t], known[t] = g, k & active[t]
    return returns, known


def drop_memory(obs: th.Tensor, memory: slice, obs_size: int, share: float, generator: th.Generator) -> th.Tensor:
    """`obs` (samples, k * obs_size: k robots' observations side by side) with the `memory` fields of each
    robot's observation set to zero with probability `share`, independently per sample and robot; a copy."""
    n = obs.shape[0]
    blocks = obs.reshape(n, -1, obs_size).clone()
    drop = th.rand(blocks.shape[:2], generator=generator) < share
    blocks[:, :, memory] = th.where(drop[:, :, None], 0.0, blocks[:, :, memory])
    return blocks.reshape(obs.shape)


def imitate(
    model: PPO,
    demo: Demonstration,
    cfg: TrainConfig,
    seed: int,
    progress: bool = False,
    memory: tuple[slice, int] | None = None,
) -> tuple[float, float]:
    """Fit `model`'s policy to `demo` (see the module); returns the last epoch's (action loss, value loss).
    `memory`: the previous command's slice of a robot's observation and that observation's size, where
    `imitation.memory_dropout` applies (the ``rich_memory`` layout)."""
    policy = model.policy
    optimizer = th.optim.Adam(policy.parameters(), lr=cfg.learning_rate)
    obs = th.as_tensor(demo.obs, dtype=th.float32)
    discrete = demo.actions.ndim == 1
    target = th.as_tensor(demo.actions, dtype=th.long if discrete else th.float32)
    returns = th.as_tensor(demo.returns, dtype=th.float32)
    generator = th.Generator().manual_seed(seed)
    batch = cfg.ppo.minibatch_size
    action_loss = value_loss = float("nan")
    policy.set_training_mode(True)
    bar = tqdm(range(cfg.imitation.epochs), desc="imitation: fit", unit="epoch", disable=not progress)
    for _ in bar:
        order = th.randperm(len(obs), generator=generator)
        totals = np.zeros(2)
        for start in range(0, len(obs), batch):
            idx = order[start : start + batch]
            x = obs[idx]
            if memory is not None and cfg.imitation.memory_dropout > 0:
                x = drop_memory(x, *memory, cfg.imitation.memory_dropout, generator)
            features = policy.extract_features(x)
            latent_pi, latent_vf = policy.mlp_extractor(features)
            head = policy.action_net(latent_pi)
            a_loss = F.cross_entropy(head, target[idx]) if discrete else F.mse_loss(head, target[idx])
            v_loss = F.mse_loss(policy.value_net(latent_vf).flatten(), returns[idx])
            optimizer.zero_grad()
            (a_loss + cfg.ppo.vf_coef * v_loss).backward()
            th.nn.utils.clip_grad_norm_(policy.parameters(), cfg.ppo.max_grad_norm)
            optimizer.step()
            totals += (a_loss.item() * len(idx), v_loss.item() * len(idx))
        action_loss, value_loss = totals / max(len(obs), 1)
        bar.set_postfix(action_loss=f"{action_loss:.4f}", value_loss=f"{value_loss:.2f}", refresh=False)
    bar.close()
    policy.set_training_mode(False)
    if not discrete:
        with th.no_grad():
            policy.log_std.fill_(cfg.imitation.log_std)
    return float(action_loss), float(value_loss)


def warm_start(
    worlds: VecWorlds, streams: StreamMap, models: list[PPO], cfg: TrainConfig, progress: bool = False
) -> ImitationResult:
    """Demonstrate, then fit every learner's policy to its share; the worlds are left mid-episode (the caller
    resets them)."""
    im = cfg.imitation
    memory = (worlds.layout.slices["previous_command"], worlds.obs_size) if worlds.layout.has_memory else None
    demos, steps, episodes = demonstrate(worlds, streams, im.steps, cfg.gamma, progress, im.teacher)
    losses = [
        imitate(m, d, cfg, cfg.seed + 104729 * i, progress, memory)
        for i, (m, d) in enumerate(zip(models, demos, strict=True))
    ]

    def students(per_learner: list[np.ndarray]) -> list[np.ndarray]:
        return [
            np.asarray(m.policy.predict(o, deterministic=True)[0]) for m, o in zip(models, per_learner, strict=True)
        ]

    for r in range(1, im.rounds):
        more, s, e = demonstrate(worlds, streams, im.steps, cfg.gamma, progress, im.teacher, driver=students)
        demos = [
            Demonstration(
                obs=np.concatenate([d.obs, n.obs]),
                actions=np.concatenate([d.actions, n.actions]),
                returns=np.concatenate([d.returns, n.returns]),
            )
            for d, n in zip(demos, more, strict=True)
        ]
        steps, episodes = steps + s, episodes + e
        losses = [
            imitate(m, d, cfg, cfg.seed + 104729 * i + 7919 * r, progress, memory)
            for i, (m, d) in enumerate(zip(models, demos, strict=True))
        ]
    return ImitationResult(
        world_steps=steps,
        samples=sum(len(d.returns) for d in demos),
        episodes=episodes,
        rounds=im.rounds,
        action_loss=float(np.mean([a for a, _ in losses])),
        value_loss=float(np.mean([v for _, v in losses])),
    )
