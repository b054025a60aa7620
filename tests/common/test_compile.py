"""The ``compile`` option: its values, and compiled updates equal to eager ones for the four algorithms.

The default tests compile with ``backend="aot_eager"`` (dynamo and AOT autograd, no code generation: Inductor takes
about a minute per graph on this CPU); the Inductor ones are slow. Inductor's random numbers match eager ones only
with ``fallback_random``.
"""

from __future__ import annotations

import pytest
import torch as th
from torch._dynamo.utils import counters

from sb3_ef.common.compile import compile_kwargs, maybe_compile
from sb3_ef.drqv2 import DrQv2, DrQv2EF
from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.tdmpc2 import TDMPC2, TDMPC2EF
from tests.helpers.tdmpc2 import TINY_EF_POLICY, TINY_POLICY

AOT_EAGER = {"backend": "aot_eager"}
FILL_STEPS = 30
ARGUMENTS = {
    DrQv2EF: {
        "policy_kwargs": {
            "net_arch": [32, 32],
            "trunk_dim": 16,
            "features_dim": 64,
            "agent_dim": 8,
            "ef_kwargs": {"rollout_hidden_dims": (16,), "decoder_channels": 8},
        },
        "ef_horizon": 3,
        "babbling_steps": 0,
    },
    DrQv2: {"policy_kwargs": {"net_arch": [32, 32], "trunk_dim": 16}},
    TDMPC2EF: {
        "policy_kwargs": TINY_EF_POLICY,
        "ef_horizon": 5,
        "babbling_steps": 0,
    },
    TDMPC2: {"policy_kwargs": TINY_POLICY},
}


def make(algorithm, **kwargs):
    arguments = {"batch_size": 8, "buffer_size": 200, "learning_starts": FILL_STEPS + 1, "seed": 0}
    env = ToyAgentEnv(size=64, max_episode_steps=20)
    return algorithm("CnnPolicy", env, **arguments, **ARGUMENTS[algorithm], **kwargs)


def batches(algorithm, count: int):
    """``count`` batches from a buffer filled by random actions."""
    model = make(algorithm)
    model.learn(FILL_STEPS)
    th.manual_seed(0)
    return [model.replay_buffer.sample(model.batch_size) for _ in range(count)]


def updates(model, samples) -> list[dict[str, th.Tensor]]:
    """One update per batch from the same random state; the agent step moves on (DrQ-v2's std follows it)."""
    th.manual_seed(1)
    model.policy.set_training_mode(True)
    logs = []
    for sample in samples:
        model.num_timesteps += 5000
        logs.append(model._update(sample))
    return logs


@pytest.fixture
def fallback_random():
    previous = th._inductor.config.fallback_random
    th._inductor.config.fallback_random = True
    th._dynamo.reset()
    counters.clear()
    yield
    th._inductor.config.fallback_random = previous
    th._dynamo.reset()


def assert_compiled_equals_eager(algorithm, compile, samples, parameter_atol: float = 1e-6) -> None:
    eager, compiled = make(algorithm), make(algorithm, compile=compile)
    for eager_logs, compiled_logs in zip(updates(eager, samples), updates(compiled, samples), strict=True):
        assert eager_logs.keys() == compiled_logs.keys()
        for key, value in eager_logs.items():
            th.testing.assert_close(compiled_logs[key], value, rtol=1e-5, atol=1e-6, msg=lambda m, k=key: f"{k}: {m}")
    compiled_state = compiled.policy.state_dict()
    for name, value in eager.policy.state_dict().items():
        th.testing.assert_close(
            compiled_state[name], value, rtol=1e-5, atol=parameter_atol, msg=lambda m, n=name: f"{n}: {m}"
        )


@pytest.mark.parametrize("algorithm", [DrQv2EF, DrQv2, TDMPC2EF, TDMPC2])
def test_compiled_updates_equal_eager_ones(algorithm, fallback_random):
    assert_compiled_equals_eager(algorithm, AOT_EAGER, batches(algorithm, 3))
    # Two graphs (host loss, actor or policy-prior loss), compiled once: no graph break, no recompilation.
    assert counters["stats"]["unique_graphs"] == 2


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", [DrQv2EF, DrQv2, TDMPC2EF, TDMPC2])
def test_inductor_updates_equal_eager_ones(algorithm, fallback_random):
    # Inductor fuses and reorders float sums. Where a gradient is zero in exact arithmetic (TD-MPC2's last conv bias:
    # SimNorm's per-group softmax ignores it), Adam turns the rounding noise into steps of up to the learning rate,
    # so the parameters get a few learning rates of tolerance; the losses of every update are still held tight.
    assert_compiled_equals_eager(algorithm, True, batches(algorithm, 3), parameter_atol=1e-3)


def test_changing_exploration_std_does_not_recompile(fallback_random):
    model = make(DrQv2EF, compile=AOT_EAGER, exploration_std="linear(1.0, 0.1, 100000)")
    stds = {model.exploration_schedule(model.num_timesteps + 5000 * (step + 1)) for step in range(20)}
    assert len(stds) == 20
    updates(model, batches(DrQv2EF, 1) * 20)
    assert counters["stats"]["unique_graphs"] == 2
    assert not counters["recompiles"]


@pytest.mark.parametrize("algorithm", [DrQv2EF, TDMPC2EF])
def test_saved_compiled_model_loads_and_trains(algorithm, tmp_path, fallback_random):
    model = make(algorithm, compile=AOT_EAGER, **({"seed_burst": False} if algorithm is TDMPC2EF else {}))
    model.learn(FILL_STEPS + 3)
    model.save(tmp_path / "model.zip")
    loaded = algorithm.load(tmp_path / "model.zip", env=ToyAgentEnv(size=64, max_episode_steps=20))
    assert loaded.compile == AOT_EAGER
    before = [param.clone() for param in loaded.policy.parameters()]
    loaded.learn(3, reset_num_timesteps=False)
    assert loaded._n_updates > model._n_updates
    assert any(not th.equal(old, new) for old, new in zip(before, loaded.policy.parameters(), strict=True))


@pytest.mark.parametrize("compile", ["fast", 1, None, {"backend": "aot_eager", "model": None}, {"modes": "default"}])
@pytest.mark.parametrize("algorithm", [DrQv2EF, DrQv2, TDMPC2EF, TDMPC2])
def test_invalid_compile_is_rejected_at_construction(algorithm, compile):
    with pytest.raises(ValueError, match=rf"compile must be False, True, one of .*'reduce-overhead'.*got {compile!r}"):
        make(algorithm, compile=compile)


@pytest.mark.parametrize(
    ("compile", "kwargs"),
    [(False, None), (True, {}), ("reduce-overhead", {"mode": "reduce-overhead"}), (AOT_EAGER, AOT_EAGER)],
)
def test_compile_kwargs(compile, kwargs):
    assert compile_kwargs(compile) == kwargs


def test_maybe_compile_leaves_eager_functions_alone():
    def double(x):
        return 2 * x

    assert maybe_compile(double, False) is double
    th.testing.assert_close(maybe_compile(double, AOT_EAGER)(th.ones(2)), th.full((2,), 2.0))
