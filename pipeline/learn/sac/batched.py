"""SAC gradient steps of several learners at once, as one batched pass over stacked weights.

stable-baselines3's ``SAC.train`` runs a gradient step of one learner as some thirty small tensor
operations and three optimizer steps. At this project's network sizes (two layers of 128) on a
CPU about a third of its time is per-operation overhead, and `independent` mode pays it once per
robot. Here the SB3 models stay the owners of the weights: every linear layer of the K
learners' actors, critics and target critics becomes one slice of a stacked (K, out, in) tensor
(the two critics of a learner side by side: 2K slices), and the SB3 modules' parameters are views
of those slices. Checkpoints, the periodic evaluations, action sampling and export read the SB3
modules as before and see every update; a gradient step is one batched pass over all K learners:

- replay: one ring buffer per learner, sampled uniformly and independently per learner;
- critic target ``r + gamma (1 - terminated) (min_j Q'_j(s', a') - alpha log pi(a'|s'))``, a' drawn
  from the current actor; critic loss ``0.5 sum_j mean (Q_j(s, a) - target)^2`` (SB3's);
- actor loss ``mean(alpha log pi(a~|s) - min_j Q_j(s, a~))`` with the critics' weights held fixed;
- entropy coefficient loss ``-mean(log alpha (log pi + target entropy))`` when it is learned;
- the three losses of every learner summed into one backward pass (their parameters are disjoint,
  so each learner's gradients are its own) and one Adam step over all parameters (Adam is per
  element: the same update as SB3's three optimizers with the same settings);
- Polyak averaging of the targets by one fused ``lerp``.

One difference from SB3's ordering: SB3 steps the critics before it evaluates the actor's loss on
them, here both losses see the critics of the start of the step (as most SAC implementations do).
The update schedule: `updates_per_transition` gradient steps per stored transition averaged over the
learners (a learner's transitions count from its `learning_starts`-th on), every learner taking each
step, once every learner has a batch. Same seed, same weights, to the bit (the batch indices and
action noise come from a generator seeded by the training seed). Replay, sampling and the steps run on the SB3
models' device (training builds them on the CPU; a benchmark can build them on a CUDA GPU), to the bit on the CPU.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch as th
from torch import nn

from pipeline.learn.sb3 import LoopSAC, progress_remaining
from pipeline.params import TrainConfig

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0  # SB3's clamp of the actor's log standard deviation
_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


def _linears(module: object) -> list[nn.Linear]:
    if not isinstance(module, nn.Module):
        raise TypeError(f"expected a torch module, got {type(module).__name__}")
    return [m for m in module.modules() if isinstance(m, nn.Linear)]


def _linear(module: object) -> nn.Linear:
    if not isinstance(module, nn.Linear):
        raise TypeError(f"expected a linear layer, got {type(module).__name__}")
    return module


class _Stack:
    """One linear layer of G networks as stacked weight (G, out, in) and bias (G, out); the source
    modules' parameters become views of their slices."""

    def __init__(self, layers: Sequence[nn.Linear]) -> None:
        self.weight = th.stack([lin.weight.detach() for lin in layers]).contiguous().requires_grad_(True)
        self.bias = th.stack([lin.bias.detach() for lin in layers]).contiguous().requires_grad_(True)
        for g, lin in enumerate(layers):
            lin.weight.data = self.weight.data[g]
            lin.bias.data = self.bias.data[g]

    def __call__(self, x: th.Tensor, frozen: bool = False) -> th.Tensor:
        w, b = (self.weight.detach(), self.bias.detach()) if frozen else (self.weight, self.bias)
        return th.baddbmm(b.unsqueeze(1), x, w.transpose(1, 2))


class _HeadStack(_Stack):
    """The actor's mean and log-std heads of K networks stacked as one (K, 2a, hidden) layer."""

    def __init__(self, mus: Sequence[nn.Linear], log_stds: Sequence[nn.Linear]) -> None:
        a = mus[0].out_features
        self.weight = (
            th.stack([th.cat([m.weight.detach(), s.weight.detach()]) for m, s in zip(mus, log_stds, strict=True)])
            .contiguous()
            .requires_grad_(True)
        )
        self.bias = (
            th.stack([th.cat([m.bias.detach(), s.bias.detach()]) for m, s in zip(mus, log_stds, strict=True)])
            .contiguous()
            .requires_grad_(True)
        )
        for k, (m, s) in enumerate(zip(mus, log_stds, strict=True)):
            m.weight.data = self.weight.data[k, :a]
            s.weight.data = self.weight.data[k, a:]
            m.bias.data = self.bias.data[k, :a]
            s.bias.data = self.bias.data[k, a:]


def _mlp(layers: Sequence[_Stack], x: th.Tensor, frozen: bool = False, last_linear: bool = True) -> th.Tensor:
    for i, layer in enumerate(layers):
        x = layer(x, frozen)
        if i < len(layers) - 1 or not last_linear:
            x = th.relu(x)
    return x


class BatchedSAC:
    """K SB3 SAC models (``LoopSAC``) trained by batched gradient steps; see the module docstring."""

    def __init__(self, models: Sequence[object], cfg: TrainConfig, seed: int) -> None:
        sacs = [m for m in models if isinstance(m, LoopSAC)]
        if len(sacs) != len(models) or not sacs:
            raise TypeError("BatchedSAC trains LoopSAC models only")
        self.models = sacs
        self.cfg = cfg
        k = len(sacs)
        self.k = k
        actors = [m.policy.actor for m in sacs]
        hidden = [_linears(a.latent_pi) for a in actors]
        self.actor_hidden = [_Stack([h[i] for h in hidden]) for i in range(len(hidden[0]))]
        self.actor_head = _HeadStack([_linear(a.mu) for a in actors], [_linear(a.log_std) for a in actors])
        self.act_dim = _linear(actors[0].mu).out_features

        def critic_stacks(attr: str) -> list[_Stack]:
            per_net = [_linears(q) for m in sacs for q in getattr(m.policy, attr).q_networks]
            if len(per_net) != 2 * k:
                raise ValueError("BatchedSAC expects two critics per learner (SB3's default)")
            return [_Stack([net[i] for net in per_net]) for i in range(len(per_net[0]))]

        self.critic = critic_stacks("critic")
        self.target = critic_stacks("critic_target")
        self.obs_dim = hidden[0][0].in_features
        self.device = self.actor_hidden[0].weight.device
        """Where the SB3 models live (their `device`); replay, sampling and the gradient steps run there too."""
        device = self.device

        dims = self.act_dim
        self.learn_alpha = cfg.sac.ent_coef == 0.0
        self.log_alpha = th.full((k,), math.log(cfg.sac.ent_coef_init), device=device, requires_grad=self.learn_alpha)
        self.fixed_alpha = th.full((k,), float(cfg.sac.ent_coef), device=device)
        self.target_entropy = -cfg.sac.target_entropy_scale * dims
        params = [t for s in (*self.actor_hidden, self.actor_head, *self.critic) for t in (s.weight, s.bias)]
        if self.learn_alpha:
            params.append(self.log_alpha)
        self.optimizer = th.optim.Adam(params, lr=self._lr(), foreach=True)
        self._target = [t for s in self.target for t in (s.weight, s.bias)]
        self._online = [t for s in self.critic for t in (s.weight, s.bias)]
        for t in self._target:
            t.requires_grad_(False)

        cap = max(int(cfg.buffer_size), cfg.batch_size)
        self.capacity = cap
        self.obs = th.zeros(k, cap, self.obs_dim, device=device)
        self.next_obs = th.zeros(k, cap, self.obs_dim, device=device)
        self.actions = th.zeros(k, cap, dims, device=device)
        self.rewards = th.zeros(k, cap, device=device)
        self.terminated = th.zeros(k, cap, device=device)
        self.pos = np.zeros(k, dtype=np.int64)
        self.size = np.zeros(k, dtype=np.int64)
        self.generator = th.Generator(device=device).manual_seed(int(seed))
        self._rows = th.arange(k, device=device).unsqueeze(1)
        self.gradient_steps = 0
        self.credit = 0.0
        """Gradient steps owed (updates_per_transition per counted transition, averaged over learners)."""

    # -- replay --------------------------------------------------------------------------------------
    def add(
        self,
        member: int,
        obs: np.ndarray,
        next_obs: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        terminated: np.ndarray,
    ) -> None:
        """Store n transitions (arrays with a leading n) of learner `member`."""
        n = len(obs)
        if n == 0:
            return
        device = self.device
        idx = th.from_numpy((self.pos[member] + np.arange(n)) % self.capacity).to(device)
        self.obs[member, idx] = th.as_tensor(np.asarray(obs, dtype=np.float32), device=device)
        self.next_obs[member, idx] = th.as_tensor(np.asarray(next_obs, dtype=np.float32), device=device)
        self.actions[member, idx] = th.as_tensor(np.asarray(actions, dtype=np.float32).reshape(n, -1), device=device)
        self.rewards[member, idx] = th.as_tensor(np.asarray(rewards, dtype=np.float32), device=device)
        self.terminated[member, idx] = th.as_tensor(np.asarray(terminated, dtype=np.float32), device=device)
        self.pos[member] = (self.pos[member] + n) % self.capacity
        self.size[member] = min(self.size[member] + n, self.capacity)

    def ready(self) -> bool:
        return bool(self.size.min() >= self.cfg.batch_size)

    def _sample(self) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
        b = self.cfg.batch_size
        sizes = th.from_numpy(self.size).to(self.device, th.float64).unsqueeze(1)
        idx = (th.rand((self.k, b), generator=self.generator, dtype=th.float64, device=self.device) * sizes).long()
        rows = self._rows
        return (
            self.obs[rows, idx],
            self.actions[rows, idx],
            self.rewards[rows, idx],
            self.next_obs[rows, idx],
            self.terminated[rows, idx],
        )

    # -- networks ------------------------------------------------------------------------------------
    def _policy_sample(self, obs: th.Tensor, noise: th.Tensor | None = None) -> tuple[th.Tensor, th.Tensor]:
        """Squashed Gaussian actions (K, B, a) and their log-probabilities (K, B), reparametrized
        (standard normal `noise` drawn from the generator unless given)."""
        mean, log_std = self._mean_log_std(obs)
        if noise is None:
            noise = th.randn(mean.shape, generator=self.generator, device=mean.device)
        action = th.tanh(mean + log_std.exp() * noise)
        log_prob = (-0.5 * noise.square() - log_std - _HALF_LOG_2PI).sum(-1)
        log_prob = log_prob - th.log(1.0 - action.square() + 1e-6).sum(-1)
        return action, log_prob

    def _mean_log_std(self, obs: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """The actor's Gaussian mean and clamped log standard deviation, (K, B, a) each."""
        out = self.actor_head(_mlp(self.actor_hidden, obs, last_linear=False))
        return out[..., : self.act_dim], th.clamp(out[..., self.act_dim :], LOG_STD_MIN, LOG_STD_MAX)

    def _q(self, layers: Sequence[_Stack], obs: th.Tensor, actions: th.Tensor, frozen: bool = False) -> th.Tensor:
        """Both critics of every learner: (K, 2, B)."""
        x = th.cat([obs, actions], dim=-1)
        k, b, d = x.shape
        x = x.unsqueeze(1).expand(k, 2, b, d).reshape(2 * k, b, d)
        return _mlp(layers, x, frozen).reshape(k, 2, b)

    def q_values(self, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """Both critics of every learner for (K, B, obs) and (K, B, a): (K, 2, B) (for checks)."""
        with th.no_grad():
            return self._q(self.critic, obs, actions)

    def actor_mean(self, obs: th.Tensor) -> th.Tensor:
        """Deterministic actions tanh(mean) for (K, B, obs) (for checks)."""
        with th.no_grad():
            return th.tanh(self._mean_log_std(obs)[0])

    # -- updates -------------------------------------------------------------------------------------
    def _lr(self) -> float:
        model = self.models[0]
        return float(model.lr_schedule(progress_remaining(model)))

    def train(self, gradient_steps: int) -> None:
        """`gradient_steps` batched gradient steps of every learner."""
        lr = self._lr()
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        gamma, tau = self.cfg.gamma**self.cfg.n_step, self.cfg.sac.tau  # a stored transition spans n_step steps
        for _ in range(gradient_steps):
            obs, actions, rewards, next_obs, terminated = self._sample()
            alpha = self.log_alpha.detach().exp() if self.learn_alpha else self.fixed_alpha
            with th.no_grad():
                next_actions, next_log_prob = self._policy_sample(next_obs)
                next_q = self._q(self.target, next_obs, next_actions).min(dim=1).values
                target = rewards + (1.0 - terminated) * gamma * (next_q - alpha.unsqueeze(1) * next_log_prob)
            q = self._q(self.critic, obs, actions)
            critic_loss = 0.5 * (q - target.unsqueeze(1)).square().mean(dim=2).sum(dim=1)
            pi_actions, log_prob = self._policy_sample(obs)
            q_pi = self._q(self.critic, obs, pi_actions, frozen=True).min(dim=1).values
            actor_loss = (alpha.unsqueeze(1) * log_prob - q_pi).mean(dim=1)
            loss = (critic_loss + actor_loss).sum()
            if self.learn_alpha:
                entropy_gap = (log_prob.detach() + self.target_entropy).mean(dim=1)
                loss = loss - (self.log_alpha * entropy_gap).sum()
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.optimizer.step()
            with th.no_grad():
                th._foreach_lerp_(self._target, self._online, tau)
        self.gradient_steps += gradient_steps
        self._sync_ent_coef()

    def _sync_ent_coef(self) -> None:
        """Keep each SB3 model's entropy coefficient in step (it is part of what a model reports)."""
        if not self.learn_alpha:
            return
        for k, model in enumerate(self.models):
            log = getattr(model, "log_ent_coef", None)
            if isinstance(log, th.Tensor):
                with th.no_grad():
                    log.copy_(self.log_alpha.detach()[k : k + 1])
