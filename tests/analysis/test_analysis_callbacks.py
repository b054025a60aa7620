import numpy as np
import pytest
import torch as th
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import configure
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from sb3_ef.analysis.callbacks import ForesightLoggerCallback
from tests.helpers.analysis import SIZE, DotEnv, FakeModel
from tests.helpers.tdmpc2 import TINY_EF_POLICY


def test_callback_logs_images_and_mask_scores_to_tensorboard(tmp_path):
    model = FakeModel(logger=configure(str(tmp_path), ["tensorboard"]))
    callback = ForesightLoggerCallback(DotEnv(), log_freq=2, steps=4)
    callback.init_callback(model)
    assert callback.on_step()  # first call: nothing logged yet
    model.num_timesteps = 2
    callback.on_step()  # second call: logs
    accumulator = EventAccumulator(str(tmp_path)).Reload()
    images = accumulator.Tags()["images"]
    assert {"foresight/prediction", "foresight/saliency"} <= set(images)
    prediction = accumulator.Images("foresight/prediction")[0]
    # rows: 3 context frames, 4 predicted, 4 true -> 3 rows x 4 columns of 16-pixel frames, 2-pixel spacing
    assert (prediction.height, prediction.width) == (3 * SIZE + 4, 4 * SIZE + 6)
    assert prediction.step == 2
    scalars = set(accumulator.Tags()["scalars"])
    expected = {"foresight/prediction_mse", "foresight/mask_precision", "foresight/mask_recall", "foresight/mask_iou"}
    assert expected <= scalars


def test_scores_compare_the_thresholded_h_a_map_with_the_agent_mask(tmp_path):
    model = FakeModel(logger=configure(str(tmp_path), []))
    callback = ForesightLoggerCallback(DotEnv(), steps=2, threshold_rule="top_fraction", fraction=0.25)
    callback.init_callback(model)
    scalars = callback.log_foresight()
    # FakeForesight's h_a drives exactly the top-left 8x8 quarter, so the top quarter of the h_a map is that region:
    # the scores are those of that region against the dot's 3x3 mask after the 2 steps
    env = DotEnv()
    env.reset(seed=0)
    for _ in range(2):
        env.step(np.array([0.5, -0.5]))
    mask = env.agent_mask()
    inside = mask[:8, :8].sum()
    assert scalars["foresight/mask_precision"] == pytest.approx(inside / 64)
    assert scalars["foresight/mask_recall"] == pytest.approx(inside / mask.sum())
    assert 0.0 <= scalars["foresight/prediction_mse"] <= 1.0


def test_bad_setups_are_refused():
    with pytest.raises(TypeError, match=r"single gymnasium\.Env"):
        ForesightLoggerCallback(make_vec_env("CartPole-v1"))
    model = FakeModel()
    model.ef = None
    with pytest.raises(ValueError, match=r"FakeModel\.ef is None"):
        ForesightLoggerCallback(DotEnv()).init_callback(model)
    with pytest.raises(ValueError, match=r"eval_env frames are \(8, 8\)"):
        ForesightLoggerCallback(DotEnv(size=8)).init_callback(FakeModel())


@pytest.mark.parametrize("algorithm", ["DrQv2EF", "TDMPC2EF"])
def test_callback_during_training_of_both_hosts(tmp_path, algorithm):
    from test_analysis_cli import TINY_DRQV2

    import sb3_ef
    from sb3_ef.analysis.callbacks import ForesightLoggerCallback
    from sb3_ef.envs.toy import ToyAgentEnv

    size, policy_kwargs = (32, TINY_DRQV2) if algorithm == "DrQv2EF" else (64, TINY_EF_POLICY)
    model = getattr(sb3_ef, algorithm)(
        "CnnPolicy", ToyAgentEnv(size=size), buffer_size=100, batch_size=4, learning_starts=6, ef_horizon=3,
        babbling_steps=0, policy_kwargs=policy_kwargs, tensorboard_log=str(tmp_path), device="cpu",
    )  # fmt: skip
    model.learn(8, callback=ForesightLoggerCallback(ToyAgentEnv(size=size), log_freq=4, steps=4))
    accumulator = EventAccumulator(str(next(tmp_path.iterdir()))).Reload()
    assert [event.step for event in accumulator.Images("foresight/saliency")] == [4, 8]
    precision = [event.value for event in accumulator.Scalars("foresight/mask_precision")]
    assert len(precision) == 2 and all(np.isnan(value) or 0 <= value <= 1 for value in precision)


def test_latent_ef_is_drawn_through_its_probe_and_training_draws_as_without_the_callback(tmp_path):
    from test_analysis_cli import TINY_DRQV2

    from sb3_ef import DrQv2EF
    from sb3_ef.envs.toy import ToyAgentEnv

    def trained(callback):
        policy_kwargs = {**TINY_DRQV2, "ef_kwargs": {**TINY_DRQV2.get("ef_kwargs", {}), "target": "latent"}}
        model = DrQv2EF(
            "CnnPolicy", ToyAgentEnv(size=32), buffer_size=100, batch_size=4, learning_starts=6, ef_horizon=3,
            babbling_steps=0, policy_kwargs=policy_kwargs, seed=0, device="cpu", tensorboard_log=str(tmp_path),
        )  # fmt: skip
        model.learn(8, callback=callback)
        return model

    logged = trained(ForesightLoggerCallback(ToyAgentEnv(size=32), log_freq=4, steps=4, probe_steps=3))
    plain = trained(None)
    assert int(logged.ef.probe_steps) == 6 and int(plain.ef.probe_steps) == 0
    accumulator = EventAccumulator(str(sorted(tmp_path.iterdir())[0])).Reload()  # the logged run's
    assert [event.step for event in accumulator.Images("foresight/saliency")] == [4, 8]
    state, plain_state = logged.policy.state_dict(), plain.policy.state_dict()
    rest = [key for key in state if "decoder" not in key and not key.endswith("probe_steps")]
    assert len(rest) < len(state)
    for key in rest:  # everything but the probe trained as without the callback
        assert th.equal(state[key], plain_state[key]), key
