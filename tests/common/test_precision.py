"""bfloat16 mixed precision (``precision="bf16"``) on every host: refused where it cannot run, saved and kept by
``load``, an update's losses within a stated tolerance of float32's on the same weights and batch, finite, the
matrix maths in bfloat16 and the outputs float32, and a resumed bf16 run equal to an uninterrupted one."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.logger import configure
from stable_baselines3.common.vec_env import DummyVecEnv
from torch import nn

from sb3_ef import CURL, SACEF, SEAR, TD3EF, TDMPC2, TDMPC2EF, TQCEF, DrQv2, DrQv2EF
from sb3_ef.common.checkpoints import ResumableCheckpointCallback, latest_checkpoint, load_checkpoint
from sb3_ef.common.precision import autocast, check_precision
from sb3_ef.envs.toy import ToyAgentEnv
from tests.helpers.drqv2 import TINY_POLICY, make_cue_env
from tests.helpers.tdmpc2 import TINY_EF_POLICY
from tests.helpers.tdmpc2 import TINY_POLICY as TDMPC2_POLICY

COMMON = {"buffer_size": 500, "batch_size": 16, "learning_starts": 20}
DRQV2_POLICY = {key: value for key, value in TINY_POLICY.items() if key not in ("agent_dim", "ef_kwargs")}
LATENT_POLICY = {**TINY_POLICY, "ef_kwargs": {"target": "latent", "rollout_hidden_dims": (16,), "projection_dim": 16}}
SB3_EF = {
    "policy_kwargs": {"net_arch": [32, 32], "features_extractor_kwargs": {"features_dim": 64}},
    "agent_dim": 8,
    "ef_horizon": 3,
    "ef_kwargs": {"rollout_hidden_dims": (16,), "decoder_channels": 8},
}
EF = {"ef_horizon": 3, "babbling_steps": 0}
#: name: (class, tiny arguments, env); SB3's NatureCNN needs 36x36 frames or more, TD-MPC2's encoder 64x64.
HOSTS: dict[str, tuple[type, dict[str, Any], Callable[[], Any]]] = {
    "DrQv2": (DrQv2, {"policy_kwargs": DRQV2_POLICY}, make_cue_env),
    "DrQv2EF": (DrQv2EF, {"policy_kwargs": TINY_POLICY, **EF}, make_cue_env),
    "DrQv2EF-latent": (DrQv2EF, {"policy_kwargs": LATENT_POLICY, **EF}, make_cue_env),
    "SEAR": (SEAR, {"policy_kwargs": {**DRQV2_POLICY, "features_dim": 64}}, lambda: ToyAgentEnv(32, agent_masks=True)),
    "CURL": (CURL, {"crop_size": 28, "policy_kwargs": {"net_arch": [32, 32]}}, make_cue_env),
    "SACEF": (SACEF, SB3_EF, lambda: make_cue_env(size=64)),
    "TD3EF": (TD3EF, SB3_EF, lambda: make_cue_env(size=64)),
    "TQCEF": (TQCEF, SB3_EF, lambda: make_cue_env(size=64)),
    "TDMPC2": (TDMPC2, {"policy_kwargs": TDMPC2_POLICY, "seed_burst": False}, lambda: make_cue_env(size=64)),
    "TDMPC2EF": (
        TDMPC2EF,
        {"policy_kwargs": TINY_EF_POLICY, "seed_burst": False, **EF},
        lambda: make_cue_env(size=64),
    ),
}


def host(name: str, env: Any = None, **overrides: Any) -> Any:
    algorithm, arguments, make_env = HOSTS[name]
    kwargs = {**COMMON, **arguments, "seed": 0, "device": "cpu", **overrides}
    return algorithm("CnnPolicy", make_env() if env is None else env, **kwargs)


def test_unknown_values_and_devices_that_cannot_run_bf16_are_refused():
    assert check_precision("fp32", "cpu") == "fp32" and check_precision("bf16", "cpu") == "bf16"
    with pytest.raises(ValueError, match=r"Unknown precision 'bf61' \(did you mean 'bf16'\?\); expected one of 'fp32'"):
        check_precision("bf61", "cpu")
    with pytest.raises(ValueError, match="precision='bf16' runs on 'cpu' and 'cuda' devices, got device 'mps'"):
        check_precision("bf16", "mps")
    with pytest.raises(ValueError, match="Unknown precision 'float16'"):
        DrQv2("CnnPolicy", make_cue_env(), precision="float16", policy_kwargs=DRQV2_POLICY, buffer_size=100)


@pytest.mark.skipif(not th.cuda.is_available(), reason="needs a GPU")
def test_a_gpu_runs_bf16_only_with_native_bfloat16():
    if th.cuda.is_bf16_supported(including_emulation=False):
        assert check_precision("bf16", "cuda") == "bf16"
    else:
        with pytest.raises(ValueError, match="needs a GPU with native bfloat16"):
            check_precision("bf16", "cuda")


def test_fp32_leaves_autocast_off_and_bf16_turns_it_on():
    with autocast("fp32", th.device("cpu")):
        assert not th.is_autocast_enabled("cpu")
    with autocast("bf16", th.device("cpu")):
        assert th.is_autocast_enabled("cpu") and th.get_autocast_dtype("cpu") == th.bfloat16


@pytest.mark.parametrize("name", list(HOSTS))
def test_every_host_trains_in_bf16_saves_the_option_and_load_keeps_it(name, tmp_path):
    assert host(name).precision == "fp32"
    model = host(name, precision="bf16", check_finite_losses=True)  # a NaN or infinite loss raises before its step
    model.learn(30)
    assert model._n_updates > 0
    model.save(tmp_path / "model.zip")
    assert type(model).load(tmp_path / "model.zip", device="cpu").precision == "bf16"


def update_logs(name: str, path: Any, precision: str) -> dict[str, float]:
    """The losses logged by one update of the model and replay buffer saved at ``path``, loaded in ``precision``,
    on a batch drawn by fixed seeds."""
    algorithm, _, env = HOSTS[name]
    model = algorithm.load(path / "model.zip", env(), device="cpu", precision=precision)
    model.load_replay_buffer(path / "buffer.pkl")
    model.set_logger(configure(None, []))
    th.manual_seed(1), np.random.seed(1)
    model.train(1, 32)
    return {key: value for key, value in model.logger.name_to_value.items() if key.endswith("_loss")}


#: bf16 keeps 8 significant bits: a loss averaged over a batch moves by a fraction of a percent (at most 0.3% in these
#: runs), or by a thousandth for a loss near 0 (an actor's -Q, TD-MPC2's policy loss, early in training).
TOLERANCE = {"rel": 0.02, "abs": 5e-3}


@pytest.mark.parametrize("name", list(HOSTS))
def test_an_update_in_bf16_gives_the_losses_of_float32_within_the_tolerance(name, tmp_path):
    trained = host(name)
    trained.learn(60)  # weights away from their initial values (TD-MPC2's zero output layers)
    trained.save(tmp_path / "model.zip")
    trained.save_replay_buffer(tmp_path / "buffer.pkl")
    expected, got = update_logs(name, tmp_path, "fp32"), update_logs(name, tmp_path, "bf16")
    assert expected.keys() == got.keys() and expected
    for key, value in expected.items():
        assert np.isfinite(got[key])
        assert got[key] == pytest.approx(value, **TOLERANCE), key


def output_dtypes(module: nn.Module) -> set[th.dtype]:
    """The dtypes ``module`` returns from now on (a forward hook records them)."""
    seen: set[th.dtype] = set()
    module.register_forward_hook(lambda _module, _inputs, output: seen.add(output.dtype))
    return seen


@pytest.mark.parametrize("name", ["DrQv2EF", "CURL", "SACEF", "TDMPC2EF"])
def test_the_updates_convolve_in_bf16(name):
    model = host(name, precision="bf16")
    first_conv = next(module for module in model.policy.modules() if isinstance(module, nn.Conv2d))
    seen = output_dtypes(first_conv)
    model.learn(22)
    assert th.bfloat16 in seen


def test_the_planner_plans_in_bf16_and_returns_float32_actions_and_plans(tmp_path):
    model = host("TDMPC2", precision="bf16")
    seen = output_dtypes(model.world_model.dynamics[0][0])
    actions, plans = model.policy.plan(th.zeros(2, 9, 64, 64, dtype=th.uint8), None, deterministic=False)
    assert seen == {th.bfloat16} and actions.dtype == plans.dtype == th.float32
    assert th.isfinite(actions).all() and th.isfinite(plans).all()
    model.policy.save(tmp_path / "policy.pth")
    assert type(model.policy).load(tmp_path / "policy.pth").precision == "bf16"


def test_sb3s_gaussian_gets_float32_parameters_under_bf16():
    """SAC's log-probability (SB3's code): in bf16 a tanh within 2e-3 of 1 rounds to 1 and log(1 - a^2) breaks."""
    model = host("SACEF", precision="bf16")
    with autocast("bf16", model.device):
        mean, log_std, _ = model.actor.get_action_dist_params(th.zeros(4, 9, 64, 64, dtype=th.uint8))
        _, log_prob = model.actor.action_log_prob(th.zeros(4, 9, 64, 64, dtype=th.uint8))
    assert mean.dtype == log_std.dtype == log_prob.dtype == th.float32


def toy_vec_env(name: str) -> DummyVecEnv:
    """A toy env whose only draws are in reset (those a checkpoint restores), of 20-step episodes."""
    size = 64 if name.startswith("TDMPC2") else 32
    return DummyVecEnv([lambda: ToyAgentEnv(size=size, max_episode_steps=20, distractor=False)])


@pytest.mark.parametrize("name", ["DrQv2EF", "TDMPC2EF"])
def test_a_killed_and_resumed_bf16_run_equals_the_uninterrupted_one(name, tmp_path):
    total, checkpoint_step = 60, 40
    arguments = {"precision": "bf16", "babbling_steps": 10}
    uninterrupted = host(name, toy_vec_env(name), **arguments)
    uninterrupted.learn(total, callback=ResumableCheckpointCallback(checkpoint_step, str(tmp_path / "a")))
    killed = host(name, toy_vec_env(name), **arguments)
    killed.learn(checkpoint_step + 10, callback=ResumableCheckpointCallback(checkpoint_step, str(tmp_path / "b")))
    del killed
    np.random.seed(123), th.manual_seed(123)  # a fresh process draws other numbers
    resumed = load_checkpoint(type(uninterrupted), latest_checkpoint(tmp_path / "b"), toy_vec_env(name))
    assert resumed.precision == "bf16"
    resumed.learn(total - checkpoint_step, reset_num_timesteps=False)
    assert resumed._n_updates == uninterrupted._n_updates > 0
    expected, got = uninterrupted.policy.state_dict(), resumed.policy.state_dict()
    for key, value in expected.items():
        assert th.equal(value, got[key]), key
