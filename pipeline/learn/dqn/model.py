"""DQN with a dueling head, double-Q targets and prioritized replay, on stable-baselines3's DQN.

``PerDQN("DuelingMlpPolicy", env)`` gives the full combination (Wang et al. 2016 dueling head,
van Hasselt et al. 2016 double-Q target, Schaul et al. 2016 proportional prioritized replay);
``PerDQN("MlpPolicy", env, prioritized=False, double_q=False)`` trains like SB3's DQN apart from the
per-sample loss bookkeeping.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import DQN
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, create_mlp
from stable_baselines3.common.type_aliases import GymEnv, PyTorchObs, ReplayBufferSamples, Schedule
from stable_baselines3.dqn.policies import DQNPolicy, QNetwork
from torch import nn
from torch.nn import functional as F

from pipeline.learn.dqn.prioritized import PrioritizedReplayBuffer, PrioritizedReplayBufferSamples
from pipeline.learn.errors import PrioritizedReplayError


class DuelingQNetwork(QNetwork):
    """Q-network with separate value and advantage streams over a shared MLP.

    Q(s, a) = V(s) + A(s, a) - mean_a' A(s, a'), the mean taken per sample. Input: observations
    (batch, *obs_shape); output: Q-values (batch, n_actions).

    Submodules, whose names are the ``state_dict`` key prefixes (stable, relied on by exporters):

    - ``features_extractor``: SB3 features extractor (FlattenExtractor: no parameters);
    - ``shared``: ``nn.Sequential`` from ``create_mlp(features_dim, 0, net_arch, activation_fn)``,
      Linear layers at the even indices ``shared.0``, ``shared.2``, ... (empty for ``net_arch=[]``);
    - ``value_head``: ``nn.Linear(latent_dim, 1)``;
    - ``advantage_head``: ``nn.Linear(latent_dim, n_actions)``;

    where ``latent_dim`` is ``net_arch[-1]``, or ``features_dim`` when ``net_arch`` is empty.
    """

    def __init__(
        self,
        observation_space: spaces.Space[Any],
        action_space: spaces.Discrete,
        features_extractor: BaseFeaturesExtractor,
        features_dim: int,
        net_arch: list[int] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        normalize_images: bool = True,
    ) -> None:
        # QNetwork.__init__ would build the plain single-stream head (an extra ``q_net`` module);
        # only the BasePolicy part of it is shared, so that constructor is called directly.
        BasePolicy.__init__(
            self,
            observation_space,
            action_space,
            features_extractor=features_extractor,
            normalize_images=normalize_images,
        )
        self.net_arch = [64, 64] if net_arch is None else list(net_arch)
        self.activation_fn = activation_fn
        self.features_dim = features_dim
        latent_dim = self.net_arch[-1] if self.net_arch else features_dim
        self.shared = nn.Sequential(*create_mlp(features_dim, 0, self.net_arch, activation_fn))
        self.value_head = nn.Linear(latent_dim, 1)
        self.advantage_head = nn.Linear(latent_dim, int(action_space.n))

    def value_and_advantage(self, obs: PyTorchObs) -> tuple[th.Tensor, th.Tensor]:
        """The two streams: V (batch, 1) and A (batch, n_actions)."""
        latent = self.shared(self.extract_features(obs, self.features_extractor))
        return self.value_head(latent), self.advantage_head(latent)

    @staticmethod
    def aggregate(value: th.Tensor, advantage: th.Tensor) -> th.Tensor:
        """Q (batch, n_actions) from V (batch, 1) and A (batch, n_actions), centring A per sample."""
        return value + advantage - advantage.mean(dim=1, keepdim=True)

    def forward(self, obs: PyTorchObs) -> th.Tensor:
        """Q-values (batch, n_actions) for observations (batch, *obs_shape)."""
        return self.aggregate(*self.value_and_advantage(obs))


class DuelingDQNPolicy(DQNPolicy):
    """DQNPolicy whose online and target networks are :class:`DuelingQNetwork`s.

    Same constructor as SB3's DQNPolicy; ``net_arch`` sizes the shared MLP. State-dict keys are
    ``q_net.<DuelingQNetwork key>`` and ``q_net_target.<DuelingQNetwork key>``.
    """

    q_net: DuelingQNetwork
    q_net_target: DuelingQNetwork

    def make_q_net(self) -> DuelingQNetwork:
        """A fresh DuelingQNetwork with its own features extractor."""
        net_args = self._update_features_extractor(self.net_args, features_extractor=None)
        return DuelingQNetwork(**net_args).to(self.device)


DuelingMlpPolicy = DuelingDQNPolicy

_PER_KWARGS = {"alpha": "per_alpha", "beta": "per_beta0", "epsilon": "per_epsilon"}


class PerDQN(DQN):
    """SB3 DQN with prioritized replay, importance-sampling weights, beta annealing and double-Q targets.

    Arguments are DQN's plus:

    :param prioritized: sample from a :class:`PrioritizedReplayBuffer` (default) instead of uniformly.
        With a custom ``replay_buffer_class`` it must be a PrioritizedReplayBuffer subclass.
    :param per_alpha: priority exponent alpha >= 0.
    :param per_beta0: importance-sampling exponent at the start of training, in [0, 1].
    :param per_beta_final: exponent at the end of training, in [0, 1]; beta moves linearly between
        the two with the training progress (``1 - _current_progress_remaining``).
    :param per_epsilon: added to |TD error| to form a priority, > 0.
    :param double_q: bootstrap from Q_target(s', argmax_a Q_online(s', a)) instead of max_a Q_target(s', a).

    Policies: SB3's "MlpPolicy", "CnnPolicy", "MultiInputPolicy" and "DuelingMlpPolicy".
    Prioritized replay needs one-step returns (``n_steps=1``) and flat (non-Dict) observations.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        **DQN.policy_aliases,
        "DuelingMlpPolicy": DuelingDQNPolicy,
    }

    def __init__(
        self,
        policy: str | type[DQNPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 1e-4,
        buffer_size: int = 1_000_000,
        learning_starts: int = 100,
        batch_size: int = 32,
        tau: float = 1.0,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 4,
        gradient_steps: int = 1,
        replay_buffer_class: type[ReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        optimize_memory_usage: bool = False,
        n_steps: int = 1,
        target_update_interval: int = 10000,
        exploration_fraction: float = 0.1,
        exploration_initial_eps: float = 1.0,
        exploration_final_eps: float = 0.05,
        max_grad_norm: float = 10,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
        *,
        prioritized: bool = True,
        per_alpha: float = 0.6,
        per_beta0: float = 0.4,
        per_beta_final: float = 1.0,
        per_epsilon: float = 1e-6,
        double_q: bool = True,
    ) -> None:
        if not per_alpha >= 0:
            raise PrioritizedReplayError("per_alpha", per_alpha, "must be >= 0")
        for name, beta in (("per_beta0", per_beta0), ("per_beta_final", per_beta_final)):
            if not 0.0 <= beta <= 1.0:
                raise PrioritizedReplayError(name, beta, "must lie in [0, 1]")
        if not per_epsilon > 0:
            raise PrioritizedReplayError("per_epsilon", per_epsilon, "must be > 0")
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            batch_size=batch_size,
            tau=tau,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            optimize_memory_usage=optimize_memory_usage,
            n_steps=n_steps,
            target_update_interval=target_update_interval,
            exploration_fraction=exploration_fraction,
            exploration_initial_eps=exploration_initial_eps,
            exploration_final_eps=exploration_final_eps,
            max_grad_norm=max_grad_norm,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        self.prioritized = prioritized
        self.per_alpha = float(per_alpha)
        self.per_beta0 = float(per_beta0)
        self.per_beta_final = float(per_beta_final)
        self.per_epsilon = float(per_epsilon)
        self.double_q = double_q
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        self._select_replay_buffer()
        super()._setup_model()

    def _select_replay_buffer(self) -> None:
        """Check the buffer class against ``prioritized`` and pass the PER settings to it."""
        given = self.replay_buffer_class
        is_prioritized_class = given is not None and issubclass(given, PrioritizedReplayBuffer)
        if not self.prioritized:
            if is_prioritized_class:
                raise PrioritizedReplayError(
                    "replay_buffer_class", given, "is a PrioritizedReplayBuffer but prioritized=False"
                )
            return
        if given is not None and not is_prioritized_class:
            raise PrioritizedReplayError(
                "replay_buffer_class",
                given,
                "must be PrioritizedReplayBuffer or a subclass when prioritized=True (or pass prioritized=False)",
            )
        if self.n_steps != 1:
            raise PrioritizedReplayError(
                "n_steps", self.n_steps, "must be 1 with prioritized replay (or pass prioritized=False)"
            )
        self.replay_buffer_class = PrioritizedReplayBuffer if given is None else given
        self.replay_buffer_kwargs = dict(self.replay_buffer_kwargs)  # leave the caller's mapping alone
        for key, attribute in _PER_KWARGS.items():
            value = getattr(self, attribute)
            if self.replay_buffer_kwargs.get(key, value) != value:
                raise PrioritizedReplayError(
                    f"replay_buffer_kwargs[{key!r}]",
                    self.replay_buffer_kwargs[key],
                    f"conflicts with {attribute} = {value!r}; set it through {attribute}",
                )
            self.replay_buffer_kwargs[key] = value

    @property
    def per_beta(self) -> float:
        """Importance-sampling exponent for the current training progress (per_beta0 -> per_beta_final)."""
        progress = min(max(1.0 - self._current_progress_remaining, 0.0), 1.0)
        return self.per_beta0 + progress * (self.per_beta_final - self.per_beta0)

    def td_targets(self, replay_data: ReplayBufferSamples | PrioritizedReplayBufferSamples) -> th.Tensor:
        """TD targets (batch, 1): r + gamma^n (1 - done) Q_target(s', a'), without gradient.

        a' = argmax_a Q_online(s', a) with ``double_q``, else argmax_a Q_target(s', a). gamma^n is
        the batch's ``discounts`` (n-step buffers) or ``gamma``.
        """
        discounts = replay_data.discounts if replay_data.discounts is not None else self.gamma
        with th.no_grad():
            next_target = self.q_net_target(replay_data.next_observations)
            if self.double_q:
                next_actions = self.q_net(replay_data.next_observations).argmax(dim=1, keepdim=True)
                next_q = th.gather(next_target, dim=1, index=next_actions)
            else:
                next_q = next_target.max(dim=1, keepdim=True).values
            return replay_data.rewards + (1 - replay_data.dones) * discounts * next_q

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        """Run `gradient_steps` updates on batches of `batch_size`.

        Each step minimises mean_i w_i * smooth_l1(Q(s_i, a_i), target_i) (w = 1 without prioritized
        replay), clips the gradient norm to ``max_grad_norm``, then sets the sampled transitions'
        priorities to |TD error| + epsilon, the TD errors being those of this step's loss. Target
        network updates stay in DQN's ``_on_step`` (every ``target_update_interval`` env steps).
        """
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        assert self.replay_buffer is not None, "the replay buffer is built by _setup_model"
        prioritized_buffer = self.replay_buffer if isinstance(self.replay_buffer, PrioritizedReplayBuffer) else None
        if prioritized_buffer is not None:
            prioritized_buffer.beta = self.per_beta

        losses: list[float] = []
        mean_weights: list[float] = []
        mean_abs_tds: list[float] = []
        for _ in range(gradient_steps):
            replay_data: ReplayBufferSamples | PrioritizedReplayBufferSamples
            if prioritized_buffer is not None:
                replay_data = prioritized_buffer.sample(batch_size, env=self._vec_normalize_env)
                weights = replay_data.weights
            else:
                replay_data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
                weights = th.ones_like(replay_data.rewards)

            target_q_values = self.td_targets(replay_data)
            current_q_values = th.gather(self.q_net(replay_data.observations), dim=1, index=replay_data.actions.long())
            per_sample_loss = F.smooth_l1_loss(current_q_values, target_q_values, reduction="none")
            loss = (weights * per_sample_loss).mean()

            self.policy.optimizer.zero_grad()
            loss.backward()
            th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()

            abs_td = (target_q_values - current_q_values.detach()).abs().reshape(-1).cpu().numpy()
            if prioritized_buffer is not None:
                assert isinstance(replay_data, PrioritizedReplayBufferSamples)
                prioritized_buffer.update_priorities(replay_data.indices, abs_td)
            losses.append(loss.item())
            mean_weights.append(weights.mean().item())
            mean_abs_tds.append(float(abs_td.mean()))

        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        if losses:
            self.logger.record("train/loss", np.mean(losses))
            self.logger.record("train/mean_weight", np.mean(mean_weights))
            self.logger.record("train/mean_abs_td", np.mean(mean_abs_tds))
        if prioritized_buffer is not None:
            self.logger.record("train/beta", prioritized_buffer.beta)
