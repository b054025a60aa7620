"""A trained policy's deterministic action as an ONNX or TorchScript file, to act without Python training code."""

from __future__ import annotations

import importlib.util
import pathlib
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from torch import nn
from torch.overrides import TorchFunctionMode
from torch.utils._python_dispatch import TorchDispatchMode

FORMATS = ("onnx", "torchscript")

#: Random draws a policy may make in ``_predict(..., deterministic=True)``: their values are frozen into the file.
_DRAWS = frozenset({th.randn, th.randn_like, th.rand, th.rand_like, th.randint, th.randperm, th.normal})
#: One sample of an index: frozen as the exponential draws of torch's method, ``argmax(probabilities / draws)``.
_CHOICES = frozenset({th.multinomial, th.Tensor.multinomial})


class _SeededOps(TorchDispatchMode):
    """Raises at a random draw of a function :class:`_RecordDraws` does not freeze (it would draw anew each call)."""

    allowed = False

    def __torch_dispatch__(self, func: Any, types: Any, args: tuple = (), kwargs: dict | None = None) -> Any:
        if not self.allowed and th.Tag.nondeterministic_seeded in func.tags:
            raise ValueError(
                f"export_policy cannot freeze the random draw {func} that the policy's deterministic _predict makes"
            )
        return func(*args, **(kwargs or {}))


class _RecordDraws(TorchFunctionMode):
    """Runs the policy as it is, keeping each random draw (of a choice: the exponential draws it is made of)."""

    def __init__(self, seeded_ops: _SeededOps) -> None:
        super().__init__()
        self.seeded_ops = seeded_ops
        self.draws: list[th.Tensor] = []

    def __torch_function__(self, func: Callable, types: Any, args: tuple = (), kwargs: dict | None = None) -> Any:
        kwargs = kwargs or {}
        if func not in _DRAWS and func not in _CHOICES:
            return func(*args, **kwargs)
        self.seeded_ops.allowed = True
        try:
            result = self._choice(func, *args, **kwargs) if func in _CHOICES else func(*args, **kwargs)
        finally:
            self.seeded_ops.allowed = False
        if func in _DRAWS:
            self.draws.append(result.detach().clone())
        return result

    def _choice(self, func: Callable, probabilities: th.Tensor, num_samples: int, *args: Any, **kwargs: Any) -> Any:
        if num_samples != 1 or args or kwargs:
            raise ValueError(f"export_policy freezes one-sample multinomial draws only, got num_samples={num_samples}")
        generator = _generator(probabilities.device)
        state = generator.get_state()
        draws = th.empty_like(probabilities).exponential_(1.0)
        after_draws = generator.get_state()
        generator.set_state(state)
        result = func(probabilities, 1)
        if not (th.equal(generator.get_state(), after_draws) and th.equal(result, _choose(probabilities, draws))):
            raise RuntimeError(
                f"export_policy cannot freeze torch {th.__version__}'s multinomial: it is not argmax(probabilities "
                "/ exponential draws)"
            )
        self.draws.append(draws)
        return result


class _ReplayDraws(TorchFunctionMode):
    """Answers each random draw with the next recorded one, so that a trace holds them as constants."""

    def __init__(self, draws: list[th.Tensor]) -> None:
        super().__init__()
        self.draws = iter(draws)

    def __torch_function__(self, func: Callable, types: Any, args: tuple = (), kwargs: dict | None = None) -> Any:
        if func in _CHOICES:
            return _choose(args[0], next(self.draws))
        if func in _DRAWS:
            return next(self.draws)
        return func(*args, **(kwargs or {}))


def _choose(probabilities: th.Tensor, draws: th.Tensor) -> th.Tensor:
    return (probabilities / draws).argmax(dim=-1, keepdim=True)


def _generator(device: th.device) -> th.Generator:
    if device.type == "cuda":
        return th.cuda.default_generators[device.index if device.index is not None else th.cuda.current_device()]
    return th.default_generator


def _record_draws(policy: BasePolicy, observations: th.Tensor) -> list[th.Tensor]:
    """The random draws of ``policy._predict(observations, deterministic=True)``, in order."""
    seeded_ops = _SeededOps()
    with th.no_grad(), _RecordDraws(seeded_ops) as recorder, seeded_ops:
        policy._predict(observations, deterministic=True)
    return recorder.draws


@contextmanager
def _unchecked_distributions() -> Iterator[None]:
    """torch.distributions' argument checks off: a branch on values that a trace cannot hold (SAC's Gaussian)."""
    validate = th.distributions.Distribution._validate_args
    th.distributions.Distribution.set_default_validate_args(False)
    try:
        yield
    finally:
        th.distributions.Distribution.set_default_validate_args(validate)


@th.jit.script_if_tracing
def _check_batch(observations: th.Tensor, batch_size: int) -> th.Tensor:
    if observations.shape[0] != batch_size:
        raise ValueError(f"This policy file takes a batch of {batch_size} observations, got {observations.shape[0]}")
    return observations


class DeterministicPolicy(nn.Module):
    """uint8 stacked frames ``(B, C, H, W)`` -> the actions ``model.predict(frames, deterministic=True)`` returns.

    SB3's ``predict`` maps ``policy._predict``'s action into the env's action space: unscaled from [-1, 1] when the
    policy squashes its output, else clipped to the bounds. The random draws ``_predict`` makes even when
    deterministic (TD-MPC2's seeded MPPI samples) are replayed from ``draws``, for a batch of ``batch_size``.

    :param policy: the trained policy (``model.policy``), in evaluation mode.
    :param draws: the draws of ``_predict``, in order (``_record_draws``).
    :param batch_size: the only batch size taken; ``None``: any.
    """

    low: th.Tensor  # registered buffers: the action bounds
    high: th.Tensor

    def __init__(self, policy: BasePolicy, draws: list[th.Tensor], batch_size: int | None) -> None:
        super().__init__()
        space = policy.action_space
        assert isinstance(space, spaces.Box)
        self.policy = policy
        self.squash_output = policy.squash_output
        self.batch_size = batch_size
        self.register_buffer("low", th.as_tensor(space.low, dtype=th.float32))
        self.register_buffer("high", th.as_tensor(space.high, dtype=th.float32))
        for index, draw in enumerate(draws):
            self.register_buffer(f"draw_{index}", draw)
        self.n_draws = len(draws)

    def forward(self, observations: th.Tensor) -> th.Tensor:
        if self.batch_size is not None:
            observations = _check_batch(observations, self.batch_size)
        with _ReplayDraws([getattr(self, f"draw_{index}") for index in range(self.n_draws)]):
            actions = self.policy._predict(observations, deterministic=True)
        actions = actions.reshape(-1, *self.low.shape)
        if self.squash_output:
            return self.low + 0.5 * (actions + 1.0) * (self.high - self.low)
        return th.minimum(th.maximum(actions, self.low), self.high)


def export_policy(
    model: Any, path: str | pathlib.Path, format: str = "onnx", batch_size: int | None = None
) -> pathlib.Path:
    """Write ``model``'s deterministic policy to ``path`` as ONNX or TorchScript (docs/deploy.md).

    The file takes a uint8 batch ``(B, C, H, W)`` of the observations ``model.predict`` takes and returns the
    float32 actions ``(B, *action_shape)`` of ``model.predict(obs, deterministic=True)``. A policy that draws
    random numbers when deterministic (TD-MPC2's seeded MPPI planner) is written with the draws of one batch
    frozen in: its file takes that batch size only and plans from a zero warm start each call.

    :param model: a model with an SB3 policy (``model.policy``), a Box action space and a Box observation space.
    :param path: the file to write, in an existing folder.
    :param format: ``"onnx"`` or ``"torchscript"``.
    :param batch_size: the only batch size the file takes; ``None``: any (1 for a policy with frozen draws).
    :return: the path written.
    """
    if format not in FORMATS:
        raise ValueError(f"format must be one of {FORMATS}, got {format!r}")
    missing = [name for name in ("onnx", "onnxscript") if format == "onnx" and importlib.util.find_spec(name) is None]
    if missing:
        raise ImportError(f"format='onnx' needs {' and '.join(missing)}: pip install 'sb3-ef[export]'")
    policy = getattr(model, "policy", None)
    if not isinstance(policy, BasePolicy):
        what = f"whose .policy is a {type(policy).__name__}" if hasattr(model, "policy") else "without one"
        raise ValueError(
            f"export_policy needs a model with an SB3 policy (model.policy), got a {type(model).__name__} {what}"
        )
    if not isinstance(policy.observation_space, spaces.Box) or not isinstance(policy.action_space, spaces.Box):
        raise ValueError(
            "export_policy needs a Box observation space and a Box action space, got "
            f"{policy.observation_space} and {policy.action_space}"
        )
    if batch_size is not None and (isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size < 1):
        raise ValueError(f"batch_size must be a positive int or None, got {batch_size!r}")
    path = pathlib.Path(path)
    if not path.parent.is_dir():
        raise ValueError(f"export_policy writes into an existing folder, got {path} ({path.parent} does not exist)")
    policy.set_training_mode(False)
    shape, dtype = policy.observation_space.shape, policy.observation_space.dtype
    example = th.as_tensor(np.zeros((batch_size or 2, *shape), dtype=dtype), device=policy.device)
    draws = _record_draws(policy, example)
    if draws and batch_size is None:
        batch_size, example = 1, example[:1]
        draws = _record_draws(policy, example)
        warnings.warn(
            f"{type(policy).__name__}'s deterministic action draws random numbers (TD-MPC2's planner, seeded): "
            "the file holds the draws of a batch of 1 and takes that batch size only (batch_size=n for n); each "
            "call is predict(obs, deterministic=True) without state (a planner starts from a zero warm start)",
            stacklevel=2,
        )
    exported = DeterministicPolicy(policy, draws, batch_size).to(policy.device).eval()
    with _unchecked_distributions():
        if format == "torchscript":
            with th.no_grad():
                traced = th.jit.trace(exported, example, check_trace=False)
            th.jit.save(th.jit.freeze(traced, optimize_numerics=False), str(path))
        else:
            dynamic = None if batch_size else {"observations": {0: th.export.Dim("batch", min=1)}}
            th.onnx.export(
                exported, (example,), str(path), input_names=["observation"], output_names=["action"],
                dynamic_shapes=dynamic, external_data=False, verbose=False,
            )  # fmt: skip
    return path
