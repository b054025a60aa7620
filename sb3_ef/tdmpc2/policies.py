"""The TD-MPC2 policies: world model, MPPI planner, optimisers and Q scale (and TDMPC2-EF's Ego-Foresight sizes)."""

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
from sb3_ef.tdmpc2.math import TwoHot, planning_iterations
from sb3_ef.tdmpc2.planner import MPPIPlanner
from sb3_ef.tdmpc2.world_model import FRAME_SIZE, WorldModel


def check_pixel_space(observation_space: spaces.Space) -> tuple[int, int, int]:
    """Check for stacked 64x64 uint8 RGB frames, channels-first, and return ``(channels, height, width)``."""
    channels, height, width = check_stacked_frames(observation_space, "TD-MPC2")
    if (height, width) != (FRAME_SIZE, FRAME_SIZE):
        raise ValueError(
            f"TD-MPC2's encoder expects {FRAME_SIZE}x{FRAME_SIZE} frames (make_env(..., size=64)), got {height}x{width}"
        )
    return channels, height, width


#: Seed of the planner's random draws in ``predict(..., deterministic=True)``, fixed so that the action is a
#: function of the observation, the warm-start plan and the weights (SB3's ``evaluate_policy`` relies on it).
DETERMINISTIC_SEED = 0


@contextmanager
def _seeded_draws(device: th.device, seed: int) -> Iterator[None]:
    """Within the block, torch's generators of the CPU and of ``device`` start from ``seed``; afterwards they are
    restored to their state before it."""
    on_cuda = device.type == "cuda"
    with th.random.fork_rng(devices=[device] if on_cuda else []):
        th.default_generator.manual_seed(seed)
        if on_cuda:
            with th.cuda.device(device):
                th.cuda.manual_seed(seed)
        yield


#: DrQ-v2 policy arguments a TD-MPC2 policy does not take, with what sizes it has instead.
_DRQV2_ARGUMENTS = {
    "net_arch": "mlp_dim (width of every MLP)",
    "features_dim": "num_channels (the latent has 16 * num_channels dims)",
    "trunk_dim": "mlp_dim",
    "n_critics": "num_q",
}


class TDMPC2Policy(CarriesAuxiliary, BasePolicy):
    """Holds everything TD-MPC2 learns and plans with, and the algorithm's auxiliary loss module, if any
    (``auxiliary``, set by the algorithm: TDMPC2-EF's Ego-Foresight).

    ``optimizer`` trains the world model (parameter groups ``encoder``, at ``encoder_lr_scale`` times the learning
    rate, and ``heads``; the algorithm adds an ``auxiliary`` group for its auxiliary module); ``pi_optimizer`` trains
    the policy prior. ``q_scale`` is the running 5-95 percentile range of Q that normalises the policy loss. Actions
    come from MPPI planning (``plan``); ``predict`` carries the warm-start plans as its state, which ``episode_start``
    resets.

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
    :param planner_kwargs: MPPI settings, see :class:`MPPIPlanner` (``num_samples``, ``eval_action``, ...);
        ``iterations`` (6 by default) gets 2 more when ``action_dim >= 20``, a given value too (TD-MPC2's heuristic).
    :param optimizer_class: optimiser of both parameter sets.
    :param optimizer_kwargs: extra optimiser arguments; ``None`` with Adam gives its fused kernel (``fused=True``:
        the same update, faster on CPU and GPU).
    :param channels_last: keep the conv weights of the encoder (and of an auxiliary module's decoder) in
        channels-last memory format (the same maths, faster convolutions with oneDNN on CPU and tensor cores on GPU).
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
        **unknown: Any,
    ):
        for name in unknown:
            instead = _DRQV2_ARGUMENTS.get(name, "see the TDMPC2Policy docstring")
            raise ValueError(f"TDMPC2Policy has no argument {name!r}: its sizes are set by {instead}")
        if optimizer_kwargs is None and optimizer_class is th.optim.Adam:
            optimizer_kwargs = {"fused": True}
        super().__init__(
            observation_space,
            action_space,
            normalize_images=False,
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
        )
        channels, height, width = check_pixel_space(observation_space)
        self.frame_shape = (FRAME_CHANNELS, height, width)
        self._constructor_kwargs: dict[str, Any] = {
            "num_channels": num_channels,
            "mlp_dim": mlp_dim,
            "num_q": num_q,
            "dropout": dropout,
            "simnorm_dim": simnorm_dim,
            "num_bins": num_bins,
            "vmin": vmin,
            "vmax": vmax,
            "encoder_lr_scale": encoder_lr_scale,
            "horizon": horizon,
            "gamma": gamma,
            "planner_kwargs": planner_kwargs,
            "channels_last": channels_last,
        }
        self.channels_last = channels_last
        self.auxiliary: AuxiliaryLoss | None = None
        action_dim = int(np.prod(action_space.shape))
        self.world_model = WorldModel(
            channels,
            action_dim,
            num_channels=num_channels,
            mlp_dim=mlp_dim,
            num_q=num_q,
            dropout=dropout,
            simnorm_dim=simnorm_dim,
            two_hot=TwoHot(num_bins, vmin, vmax),
        )
        if channels_last:
            self.world_model.encoder.to(memory_format=th.channels_last)  # type: ignore[call-overload]
        planner_kwargs = dict(planner_kwargs or {})
        iterations = planning_iterations(action_dim, planner_kwargs.pop("iterations", MPPIPlanner.iterations))
        self.planner = MPPIPlanner(horizon=horizon, gamma=gamma, iterations=iterations, **planner_kwargs)
        self.register_buffer("q_scale", th.ones(()))
        self._build_optimizers(lr_schedule(1), encoder_lr_scale)

    def _build_optimizers(self, learning_rate: float, encoder_lr_scale: float) -> None:
        """``optimizer`` of the world model (groups ``encoder``, at ``encoder_lr_scale`` times the rate, and
        ``heads``: dynamics, reward, Q) and ``pi_optimizer`` of the policy prior (Adam's ``eps`` 1e-5, as TD-MPC2)."""
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
        """Latent z (the features h that EF splits) of uint8 stacked observations, without augmentation."""
        return self.world_model.encode(observations)

    def plan(
        self, observations: th.Tensor, previous_mean: th.Tensor | None, deterministic: bool
    ) -> tuple[th.Tensor, th.Tensor]:
        """MPPI actions ``(n_envs, action_dim)`` for stacked observations and the plan mean for the next call."""
        with th.no_grad():
            return self.planner.plan(self.world_model, self.encode(observations), previous_mean, deterministic)

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """SB3's ``predict``, the planner's warm start carried as the state (as a recurrent policy carries its own).

        ``state`` is what the previous call returned, ``(plans,)``: the final MPPI means ``(n_envs, horizon,
        action_dim)``, which warm-start this call's plans shifted by one step; the returned state holds this call's
        plans for the next one. ``state=None`` and the envs where ``episode_start`` is true plan from a zero mean
        (an episode's first step). So the action is a function of the observation, the state and the weights, with
        the random draws of :meth:`_plan_actions`.
        """
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
        clipped = np.clip(actions.cpu().numpy(), self.action_space.low, self.action_space.high)  # type: ignore[attr-defined]
        return (clipped if vectorized else clipped.squeeze(axis=0)), (plans.cpu().numpy(),)

    def _warm_start(
        self, state: tuple[np.ndarray, ...] | None, episode_start: np.ndarray | None, n_envs: int
    ) -> th.Tensor | None:
        """The previous plans held in ``predict``'s ``state``, zero for the envs where ``episode_start`` is true
        (``None``: every env starts from a zero mean); raise naming the expected shapes."""
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
        """:meth:`plan`; with ``deterministic``, the planner's random draws (samples, policy-prior noise, Q heads,
        elite draw) come from generators seeded with :data:`DETERMINISTIC_SEED` at each call, and the global
        generators are left as they were (an evaluation does not shift training's random stream). Otherwise they
        come from the global generators, as training's do."""
        with _seeded_draws(observations.device, DETERMINISTIC_SEED) if deterministic else nullcontext():
            return self.plan(observations, previous_mean, deterministic)

    def _predict(self, observation: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        """The planner's actions from a zero warm start (an episode's first step); :meth:`predict` carries the
        warm start from call to call."""
        assert isinstance(observation, th.Tensor)
        return self._plan_actions(observation, None, deterministic)[0]


class TDMPC2EFPolicy(TDMPC2Policy):
    """:class:`TDMPC2Policy` of TDMPC2-EF: the first ``agent_dim`` dimensions of the latent are the agent's;
    TDMPC2EF builds its Ego-Foresight module from these sizes.

    :param agent_dim: size of the agent part of the latent (a multiple of ``simnorm_dim``, whole SimNorm groups).
    :param ef_kwargs: extra arguments of :class:`sb3_ef.ef.EgoForesight` (decoder and rollout options).
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
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)
        simnorm_dim = self._constructor_kwargs["simnorm_dim"]
        if agent_dim % simnorm_dim != 0:
            raise ValueError(
                f"agent_dim must cover whole SimNorm groups: expected a multiple of {simnorm_dim}, got {agent_dim}"
            )
        self.agent_dim = agent_dim
        self.ef_kwargs = ef_kwargs or {}

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "agent_dim": self.agent_dim, "ef_kwargs": self.ef_kwargs}
