"""export_policy: every host's ONNX and TorchScript files act as ``predict(obs, deterministic=True)`` on real DMC
frames (onnxruntime, torch.jit.load), and bad arguments are refused by name."""

from __future__ import annotations

import numpy as np
import onnxruntime
import pytest
import torch as th
from gymnasium.wrappers import RescaleAction

import sb3_ef
from sb3_ef import CURL, SACEF, SEAR, TD3EF, TDMPC2, TDMPC2EF, TQCEF, DrQv2, DrQv2EF, export_policy
from sb3_ef.drqv2.policies import DrQv2Encoder

EF = {"agent_dim": 8, "ef_kwargs": {"rollout_hidden_dims": [16], "decoder_channels": 8}}
DRQV2 = {"net_arch": [16], "trunk_dim": 8, "features_dim": 32}
TD_MPC2 = {
    "num_channels": 4, "mlp_dim": 16, "num_q": 3, "num_bins": 11,
    "planner_kwargs": {"iterations": 2, "num_samples": 16, "num_elites": 4, "num_pi_trajs": 2},
}  # fmt: skip
TD_MPC2_EF = {**TD_MPC2, **EF, "agent_dim": 16}  # whole SimNorm groups
SB3_CNN = {
    "net_arch": [16], "normalize_images": False,  # DrQv2Encoder scales the frames itself
    "features_extractor_class": DrQv2Encoder, "features_extractor_kwargs": {"features_dim": 32},
}  # fmt: skip
SMALL = {"buffer_size": 100, "seed": 0, "device": "cpu"}
PLAN_SMALL = {**SMALL, "horizon": 1}  # a short plan: the planner's graph, traced, is unrolled
HOSTS = {
    DrQv2: lambda env: DrQv2("CnnPolicy", env, policy_kwargs=DRQV2, **SMALL),
    DrQv2EF: lambda env: DrQv2EF("CnnPolicy", env, policy_kwargs={**DRQV2, **EF}, **SMALL),
    SEAR: lambda env: SEAR("CnnPolicy", env, policy_kwargs=DRQV2, **SMALL),
    TDMPC2: lambda env: TDMPC2("CnnPolicy", env.env, policy_kwargs=TD_MPC2, **PLAN_SMALL),
    TDMPC2EF: lambda env: TDMPC2EF("CnnPolicy", env.env, policy_kwargs=TD_MPC2_EF, **PLAN_SMALL),
    CURL: lambda env: CURL("CnnPolicy", env, crop_size=56, features_dim=16, policy_kwargs={"net_arch": [16]}, **SMALL),
    SACEF: lambda env: SACEF("CnnPolicy", env, policy_kwargs=dict(SB3_CNN), **EF, **SMALL),
    TD3EF: lambda env: TD3EF("CnnPolicy", env, policy_kwargs=dict(SB3_CNN), **EF, **SMALL),
    TQCEF: lambda env: TQCEF("CnnPolicy", env, policy_kwargs=dict(SB3_CNN), **EF, **SMALL),
}
#: Hosts whose deterministic action draws seeded random numbers (TD-MPC2's planner): files of one batch size.
PLANNERS = (TDMPC2, TDMPC2EF)


@pytest.fixture(scope="module")
def env_and_frames():
    """Cartpole with actions rescaled to [-2, 3] (TD-MPC2 gets the [-1, 1] env inside) and 3 stacked real frames."""
    env = RescaleAction(
        sb3_ef.make_env("dmc/cartpole-swingup-v0", size=64, frame_stack=2, agent_masks=True, fast_render=True, seed=0),
        np.float32(-2.0), np.float32(3.0),
    )  # fmt: skip
    frames = [env.reset(seed=0)[0]]
    for action in (-2.0, 3.0):  # the cart pushed one way, then the other, to frames apart
        for _ in range(10):
            observation = env.step(np.array([action], dtype=np.float32))[0]
        frames.append(observation)
    yield env, np.stack(frames)
    env.close()


def trained_like(model):
    """``model`` with its weights moved off their initialisation, as training moves them: TD-MPC2's zero-initialised
    reward and Q heads otherwise tie every plan's value, and onnxruntime breaks ties as torch may not."""
    with th.no_grad():
        for parameter in model.policy.parameters():
            parameter.add_(0.1 * th.randn_like(parameter))
    return model


#: What each runtime says when a planner's file of batch size 1 gets 3 observations.
REFUSALS = {"onnx": "Got: 3 Expected: 1", "torchscript": "takes a batch of 1 observations, got 3"}


def run_onnx(path, observations: np.ndarray) -> np.ndarray:
    return onnxruntime.InferenceSession(str(path)).run(["action"], {"observation": observations})[0]


def run_torchscript(path, observations: np.ndarray) -> np.ndarray:
    return th.jit.load(str(path))(th.as_tensor(observations)).numpy()


@pytest.mark.parametrize("algorithm", HOSTS, ids=lambda algorithm: algorithm.__name__)
def test_exported_policy_acts_as_predict(algorithm, env_and_frames, tmp_path):
    env, frames = env_and_frames
    model = trained_like(HOSTS[algorithm](env))
    batches = [frames[i : i + 1] for i in range(len(frames))] if algorithm in PLANNERS else [frames, frames[1:2]]
    if algorithm not in PLANNERS:  # the frames give actions further apart than the tolerance (a plan may hit a bound)
        assert np.ptp(model.predict(frames, deterministic=True)[0]) > 1e-3
    for format, run in (("onnx", run_onnx), ("torchscript", run_torchscript)):
        path = tmp_path / f"policy.{format}"
        if algorithm in PLANNERS:
            with pytest.warns(UserWarning, match="takes that batch size only"):
                assert export_policy(model, path, format) == path
            with pytest.raises(Exception, match=REFUSALS[format]):
                run(path, frames)
        else:
            assert export_policy(model, str(path), format=format) == path
        for observations in batches:
            expected, _ = model.predict(observations, deterministic=True)
            actions = run(path, observations)
            assert actions.dtype == np.float32 and actions.shape == expected.shape
            np.testing.assert_allclose(actions, expected, rtol=0, atol=2e-6)


def test_a_planner_file_of_another_batch_size_holds_that_batch(env_and_frames, tmp_path):
    env, frames = env_and_frames
    model = trained_like(HOSTS[TDMPC2](env))
    path = export_policy(model, tmp_path / "planner.pt", "torchscript", batch_size=3)
    expected, _ = model.predict(frames, deterministic=True)
    np.testing.assert_allclose(run_torchscript(path, frames), expected, rtol=0, atol=2e-6)
    with pytest.raises(Exception, match="takes a batch of 3 observations, got 1"):
        run_torchscript(path, frames[:1])


def test_bad_arguments_are_refused_by_name(env_and_frames, tmp_path):
    env, _ = env_and_frames
    model = DrQv2("CnnPolicy", env, policy_kwargs=DRQV2, **SMALL)
    with pytest.raises(ValueError, match=r"format must be one of \('onnx', 'torchscript'\), got 'tflite'"):
        export_policy(model, tmp_path / "policy.tflite", format="tflite")
    with pytest.raises(ValueError, match=r"existing folder, got .*missing/policy.onnx \(.*missing does not exist\)"):
        export_policy(model, tmp_path / "missing" / "policy.onnx")
    with pytest.raises(ValueError, match="batch_size must be a positive int or None, got 0"):
        export_policy(model, tmp_path / "policy.onnx", batch_size=0)
    assert not list(tmp_path.iterdir())


def test_a_model_without_an_sb3_policy_is_refused_naming_it(tmp_path):
    from sb3_ef.dreamerv3 import DreamerV3  # the workbench's sheeprl wrapper: it acts through sheeprl's player

    model = DreamerV3("CnnPolicy", None, work_dir=tmp_path, device="cpu")
    with pytest.raises(ValueError, match=r"SB3 policy \(model.policy\), got a DreamerV3 without one"):
        export_policy(model, tmp_path / "policy.onnx")
