"""The TD-MPC2 and TDMPC2-EF policies: world model, MPPI planner, optimisers and Q scale."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule

from sb3_ef.auxiliary.loss import AuxiliaryLoss, CarriesAuxiliary
from sb3_ef.common.env_checks import FRAME_CHANNELS, check_stacked_frames
from sb3_ef.common.forwarding import base_arguments
from sb3_ef.common.precision import PRECISIONS, autocast
from sb3_ef.common.validation import check_choice
from sb3_ef.ef.host import EFPolicyMixin
from sb3_ef.tdmpc2.math import TwoHot, planning_iterations
from sb3_ef.tdmpc2.planner import MPPIPlanner
from sb3_ef.tdmpc2.world_model import FRAME_SIZE, WorldModel


def check_pixel_space(observation_space: spaces.Space) -> tuple[int, int, int]:
    """``(channels, height, width)`` of stacked 64x64 uint8 RGB frames, channels-first, or raise."""
    channels, height, width = check_stacked_frames(observation_space, "TD-MPC2")
    if (height, width) != (FRAME_SIZE, FRAME_SIZE):
        raise ValueError(
            f"TD-MPC2's encoder expects {FRAME_SIZE}x{FRAME_SIZE} frames (make_env(..., size=64)), got {height}x{width}"
        )
    return channels, height, width


#: Seed of the planner's draws in ``predict(..., deterministic=True)``: the action is a function of its inputs.
DETERMINISTIC_SEED = 0


@contextmanager
def _seeded_draws(device: th.device, seed: int) -> Iterator[None]:
    """Torch's CPU and ``device`` generators seeded with ``seed`` within the block, restored after it."""
    on_cuda = device.type == "cuda"
    with th.random.fork_rng(devices=[device] if on_cuda else []):
        th.default_generator.manual_seed(seed)
        if on_cuda:
            with th.cuda.device(device):
                th.cuda.manual_seed(seed)
        yield


#: DrQ-v2's and SB3's policy arguments a TD-MPC2 policy does not take, with what it has instead.
_NOT_TAKEN = {
    "net_arch": "its sizes are set by mlp_dim (width of every MLP)",
    "features_dim": "its sizes are set by num_channels (the latent has 16 * num_channels dims)",
    "trunk_dim": "its sizes are set by mlp_dim",
    "n_critics": "its sizes are set by num_q",
    "normalize_images": "its encoder always scales the uint8 frames itself (frames / 255 - 0.5, as TD-MPC2)",
}


class TDMPC2Policy(CarriesAuxiliary, BasePolicy):
    """World model, planner and ``auxiliary``; ``predict``'s state is the MPPI warm start (docs/tdmpc2.md).

    :param observation_space: uint8 Box (3 * frame_stack, 64, 64).
    :param action_space: Box in [-1, 1].
    :param lr_schedule: learning rate schedule (the algorithm updates the rates during training).
    :param num_channels: conv channels; the latent size is ``16 * num_channels`` (512 by default).
    :param mlp_dim: hidden size of the dynamics, reward, policy and Q MLPs.
    :param num_q: number of Q heads.
    :param dropout: dropout in the first layer of the Q heads.
    :param simnorm_dim: SimNorm group size.
    :param num_bins: two-hot bins of reward and Q.
    :param vmin: lower end of the bins (symlog space).
    :param vmax: upper end of the bins (symlog space).
    :param encoder_lr_scale: encoder learning rate relative to the rest.
    :param horizon: planning / world-model horizon (set by the algorithm).
    :param gamma: discount of the planner's value estimate (set by the algorithm).
    :param planner_kwargs: see :class:`MPPIPlanner` (``iterations`` + 2 when ``action_dim >= 20``, as TD-MPC2).
    :param optimizer_class: optimiser of both parameter sets.
    :param optimizer_kwargs: extra optimiser arguments; ``None`` with Adam gives its fused kernel.
    :param channels_last: keep the conv weights (encoder, auxiliary decoder) channels-last (faster convolutions).
    :param precision: the planner's ``"fp32"`` or ``"bf16"`` (set by the algorithm's ``precision``).
    """

    q_scale: th.Tensor  # a registered buffer

    def __init__(
        self,
        observation_space: spaces.Box,
        action_space: spaces.Box,
        lr_schedule: Schedule,
        num_channels: int = 32,
        mlp_dim: int = 512,
        num_q: int = 5,
        dropout: float = 0.01,
        simnorm_dim: int = 8,
        num_bins: int = 101,
        vmin: float = -10.0,
        vmax: float = 10.0,
        encoder_lr_scale: float = 0.3,
        horizon: int = 3,
        gamma: float = 0.99,
        planner_kwargs: dict[str, Any] | None = None,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
        channels_last: bool = True,
        precision: str = "fp32",
        **unknown: Any,
    ):
        for name in unknown:
            instead = _NOT_TAKEN.get(name, "its arguments are listed in the TDMPC2Policy docstring")
            raise ValueError(f"TDMPC2Policy has no argument {name!r}: {instead}")
        if optimizer_kwargs is None and optimizer_class is th.optim.Adam:
            optimizer_kwargs = {"fused": True}
        super().__init__(
            observation_space,
            action_space,
            normalize_images=False,
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
            squash_output=True,  # the plan acts in [-1, 1]: predict and exports unscale it to the env's bounds
        )
        channels, height, width = check_pixel_space(observation_space)
        self.frame_shape = (FRAME_CHANNELS, height, width)
        self._constructor_kwargs = base_arguments(TDMPC2Policy, locals())
        self.channels_last = channels_last
        check_choice("precision", precision, PRECISIONS)  # the algorithm checks it against its device
        self.precision = precision
        self.auxiliary: AuxiliaryLoss | None = None
        action_dim = int(np.prod(action_space.shape))
        two_hot = TwoHot(num_bins, vmin, vmax)
        self.world_model = WorldModel(channels, action_dim, num_channels, mlp_dim, num_q, dropout, simnorm_dim, two_hot)
        if channels_last:
            self.world_model.encoder.to(memory_format=th.channels_last)  # type: ignore[call-overload]
        planner_kwargs = dict(planner_kwargs or {})
        iterations = planning_iterations(action_dim, planner_kwargs.pop("iterations", MPPIPlanner.iterations))
        self.planner = MPPIPlanner(horizon=horizon, gamma=gamma, iterations=iterations, **planner_kwargs)
        self.register_buffer("q_scale", th.ones(()))
        self._build_optimizers(lr_schedule(1), encoder_lr_scale)

    def _build_optimizers(self, learning_rate: float, encoder_lr_scale: float) -> None:
        """The world model's ``optimizer`` and the policy prior's ``pi_optimizer`` (``eps`` 1e-5, as TD-MPC2)."""
        model = self.world_model
        groups: list[dict[str, Any]] = [
            {"name": "encoder", "params": model.encoder.parameters(), "lr_scale": encoder_lr_scale},
            {
                "name": "heads",
                "params": [*model.dynamics.parameters(), *model.reward_head.parameters(), *model.q_heads.parameters()],
            },
        ]
        for group in groups:
            group["lr"] = learning_rate * group.get("lr_scale", 1.0)
        # torch's stub of Optimizer.__init__ has no ``lr``; every optimiser class takes it.
        self.optimizer = self.optimizer_class(groups, lr=learning_rate, **self.optimizer_kwargs)  # type: ignore[call-arg]
        self.pi_optimizer = self.optimizer_class(  # type: ignore[call-arg]
            model.pi_head.parameters(), lr=learning_rate, **{"eps": 1e-5, **self.optimizer_kwargs}
        )

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        del data["normalize_images"]  # fixed: the encoder scales images itself
        data.update(
            self._constructor_kwargs,
            lr_schedule=self._dummy_schedule,
            optimizer_class=self.optimizer_class,
            optimizer_kwargs=self.optimizer_kwargs,
        )
        return data

    def encode(self, observations: th.Tensor) -> th.Tensor:
        """Latent z of uint8 stacked observations."""
        return self.world_model.encode(observations)

    def plan(
        self, observations: th.Tensor, previous_mean: th.Tensor | None, deterministic: bool
    ) -> tuple[th.Tensor, th.Tensor]:
        """MPPI actions ``(n_envs, action_dim)`` for stacked observations and the plan mean for the next call."""
        with th.no_grad(), autocast(self.precision, observations.device):
            return self.planner.plan(self.world_model, self.encode(observations), previous_mean, deterministic)

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """SB3's ``predict``; the state is the planner's warm start (see docs/tdmpc2.md)."""
        if isinstance(observation, tuple):
            raise ValueError(
                "predict expects the observation as an array (a VecEnv's obs, or the obs of gymnasium's "
                "obs, info = env.reset()), got a tuple"
            )
        self.set_training_mode(False)
        observations, vectorized = self.obs_to_tensor(observation)
        assert isinstance(observations, th.Tensor)
        previous = self._warm_start(state, episode_start, observations.shape[0])
        actions, plans = self._plan_actions(observations, previous, deterministic)
        # The plan acts in [-1, 1] (the buffer's scale): the env's bounds, as the rollouts' actions are.
        env_actions = self.unscale_action(actions.cpu().numpy())
        return (env_actions if vectorized else env_actions.squeeze(axis=0)), (plans.cpu().numpy(),)

    def _warm_start(
        self, state: tuple[np.ndarray, ...] | None, episode_start: np.ndarray | None, n_envs: int
    ) -> th.Tensor | None:
        """The plans of ``predict``'s ``state``, zeroed where ``episode_start``; raise naming the expected shapes."""
        if state is None:
            return None
        expected = (n_envs, self.planner.horizon, int(np.prod(self.action_space.shape)))  # type: ignore[arg-type]
        if not isinstance(state, tuple) or len(state) != 1 or np.shape(state[0]) != expected:
            shapes = [np.shape(part) for part in state] if isinstance(state, tuple) else type(state).__name__
            raise ValueError(
                "predict expects state=None or the state its previous call returned for these envs, (plans,) with "
                f"plans of shape {expected} (n_envs, horizon, action_dim), got {shapes}"
            )
        plans = th.as_tensor(np.asarray(state[0], dtype=np.float32), device=self.device).clone()
        if episode_start is not None:
            starts = np.asarray(episode_start, dtype=bool).reshape(-1)
            if starts.shape != (n_envs,):
                raise ValueError(f"predict expects one episode_start flag per env ({n_envs}), got {starts.shape[0]}")
            plans[th.as_tensor(starts, device=self.device)] = 0.0
        return plans

    def _plan_actions(
        self, observations: th.Tensor, previous_mean: th.Tensor | None, deterministic: bool
    ) -> tuple[th.Tensor, th.Tensor]:
        """:meth:`plan`; ``deterministic`` draws from seeded generators, leaving training's stream as it was."""
        with _seeded_draws(observations.device, DETERMINISTIC_SEED) if deterministic else nullcontext():
            return self.plan(observations, previous_mean, deterministic)

    def _predict(self, observation: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        """The planner's actions from a zero warm start."""
        assert isinstance(observation, th.Tensor)
        return self._plan_actions(observation, None, deterministic)[0]


class TDMPC2EFPolicy(EFPolicyMixin, TDMPC2Policy):
    """:class:`TDMPC2Policy` with the sizes TDMPC2-EF's Ego-Foresight module is built from.

    :param agent_dim: size of the agent part of the latent (a multiple of ``simnorm_dim``, whole SimNorm groups).
    :param ef_kwargs: extra arguments of :class:`sb3_ef.ef.EgoForesight`.
    :param kwargs: the arguments of :class:`TDMPC2Policy`.
    """

    def __init__(
        self,
        observation_space: spaces.Box,
        action_space: spaces.Box,
        lr_schedule: Schedule,
        agent_dim: int = 32,
        ef_kwargs: dict[str, Any] | None = None,
        **kwargs: Any,
    ):
        super().__init__(
            observation_space, action_space, lr_schedule, agent_dim=agent_dim, ef_kwargs=ef_kwargs, **kwargs
        )
        simnorm_dim = self._constructor_kwargs["simnorm_dim"]
        if agent_dim % simnorm_dim != 0:
            raise ValueError(
                f"agent_dim must cover whole SimNorm groups: expected a multiple of {simnorm_dim}, got {agent_dim}"
            )
