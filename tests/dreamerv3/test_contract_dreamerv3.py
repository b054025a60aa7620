"""SB3's contract on DreamerV3: SB3's callback tests (stable_baselines3 tests/test_callbacks.py) adapted, and
deterministic and vectorised predict, the device fallback, the checks of sheeprl_overrides and of frame sizes."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from tests.dreamerv3.dreamerv3_tiny import TINY, tiny, toy

pytest.importorskip("sheeprl")

from sb3_ef.dreamerv3 import DreamerV3


def test_callbacks_see_sb3s_locals_and_counters(trained):
    """SB3's ``test_callbacks``: the locals of the last step, shared by the children; the counters of the first
    ``learn``, stopped at the end of its first episode; then ``learn`` again without a callback, with a list and the
    progress bar, and with a function."""
    model, callback = trained.model, trained.callback
    assert trained.first == {"steps": 25, "event_steps": 25, "event_calls": 25}  # StopTrainingOnMaxEpisodes
    assert trained.max_episodes.n_episodes == 1
    assert model.env.observation_space.contains(callback.locals["new_obs"][0])
    assert trained.max_episodes.locals["new_obs"] is callback.locals["new_obs"]  # (the others learned again since)
    assert trained.event.locals["new_obs"] is callback.locals["new_obs"]
    assert trained.on_event.locals["new_obs"] is callback.locals["new_obs"]
    assert model.num_timesteps == 37
    assert trained.recorder.steps == [*range(1, 26), *range(30, 34)]
    assert trained.recorder.events == ["start at 0 of 40", "end", "start at 29 of 33", "end"]


def test_the_locals_are_those_of_a_one_env_dummy_vec_env(trained):
    [end] = trained.recorder.episode_ends  # the toy env's time limit, at step 25
    info = end["infos"][0]
    assert end["new_obs"].shape == (1, 3, 16, 16) and end["new_obs"].dtype == np.uint8
    assert end["rewards"].shape == (1,) and end["dones"].tolist() == [True]
    assert info["TimeLimit.truncated"] and info["terminal_observation"].shape == (3, 16, 16)
    assert not np.array_equal(info["terminal_observation"], end["new_obs"][0])  # new_obs starts the next episode
    assert trained.model.get_env().num_envs == 1


def test_checkpoint_and_eval_callbacks_save_the_weights_of_their_step(trained):
    files = {path.name for path in trained.logs.iterdir()}
    assert {"rl_model_10_steps.zip", "rl_model_20_steps.zip", "event_10_steps.zip", "event_20_steps.zip"} <= files
    assert {"best_model.zip", "evaluations.npz"} <= files
    assert DreamerV3.load(trained.logs / "rl_model_20_steps.zip", device="cpu").num_timesteps == 20
    with np.load(trained.logs / "evaluations.npz") as evaluations:
        assert evaluations["timesteps"].tolist() == [10, 20]


class AlwaysFailCallback(BaseCallback):
    def __init__(self, callback_false_value):
        super().__init__()
        self.callback_false_value = callback_false_value

    def _on_step(self) -> bool:
        return self.callback_false_value


def test_callbacks_can_cancel_runs_and_learn_continues_from_the_stop(tmp_path):
    """SB3's ``test_callbacks_can_cancel_runs``, each falsy value stopping one ``learn`` at its first step."""
    model = tiny(tmp_path)
    for calls, value in enumerate([False, np.bool_(0), th.tensor(0, dtype=th.bool)], start=1):
        stopper = AlwaysFailCallback(callback_false_value=value)
        assert model.learn(10, callback=stopper, reset_num_timesteps=calls == 1) is model
        assert stopper.n_calls == 1 and model.num_timesteps == calls


def test_an_exception_in_a_callback_propagates_and_learn_can_continue(tmp_path):
    class Failing(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps == 3:
                raise ArithmeticError("the callback's own error")
            return True

    model = tiny(tmp_path)
    with pytest.raises(ArithmeticError, match="the callback's own error"):
        model.learn(10, callback=Failing(), checkpoint_freq=2)
    assert model.num_timesteps == 3  # the weights of step 3, on from the replay buffer of the checkpoint at step 2
    assert model.learn(2, reset_num_timesteps=False).num_timesteps == 5


def test_deterministic_predict_is_the_same_for_the_same_observation(trained):
    observation, _ = toy().reset(seed=3)
    actions = np.stack([trained.model.predict(observation, deterministic=True)[0] for _ in range(5)])
    np.testing.assert_array_equal(actions, np.repeat(actions[:1], 5, axis=0))
    sampled = np.stack([trained.model.predict(observation)[0] for _ in range(5)])
    assert np.ptp(sampled, axis=0).max() > 0  # without deterministic, actions are drawn


def test_vectorised_predict_acts_on_each_observation_as_alone(trained):
    observations = np.stack([toy().reset(seed=seed)[0] for seed in range(3)])
    actions, state = trained.model.predict(observations, deterministic=True)
    assert actions.shape == (3, 2) and state[0].shape[1] == 3
    alone = np.stack([trained.model.predict(observation, deterministic=True)[0] for observation in observations])
    np.testing.assert_allclose(actions, alone, rtol=0, atol=1e-6)


def test_frames_of_another_size_than_the_trained_one_are_named(trained, tmp_path):
    with pytest.raises(ValueError, match="trained on 16x16 frames, the observation gives 32x32"):
        trained.model.predict(toy(size=32).reset(seed=0)[0])
    trained.model.save(tmp_path / "model.zip")
    with pytest.raises(ValueError, match="trained on 16x16 frames, the env gives 32x32"):
        DreamerV3.load(tmp_path / "model.zip", env=toy(size=32), device="cpu", work_dir=tmp_path / "work")


@pytest.mark.skipif(th.cuda.is_available(), reason="the fallback is for machines without CUDA")
def test_cuda_without_a_gpu_falls_back_to_the_cpu_with_a_warning(tmp_path):
    with pytest.warns(UserWarning, match="CUDA"):
        model = DreamerV3("CnnPolicy", toy(), **TINY, work_dir=tmp_path, device="cuda")
    assert model.device == "cpu"


def test_nested_sheeprl_overrides_are_merged_key_by_key(tmp_path):
    overrides = {"algo": {"horizon": 5, "actor": {"ent_coef": 1e-3}}}
    model = DreamerV3("CnnPolicy", toy(), sheeprl_overrides=overrides, work_dir=tmp_path)
    assert model.recipe.sheeprl_overrides == {"algo.horizon": 5, "algo.actor.ent_coef": 1e-3}
    assert (model.cfg.algo.horizon, model.cfg.algo.actor.ent_coef) == (5, 1e-3)
    assert model.cfg.algo.name == "dreamer_v3" and model.cfg.algo.actor.optimizer.lr == 3e-5  # the rest kept


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ("algo.horizon=5", r"dotted \(\{'algo.horizon': 15\}\) or nested .* got 'algo.horizon=5' \(str\)"),
        ({"algo.horizn": 5}, r"'algo.horizn' is not a key .*did you mean 'algo.horizon'"),
        ({"algo": {"horizn": 5}}, r"'algo.horizn' is not a key .*did you mean 'algo.horizon'"),
        ({"algo": {"total_steps": 5}}, r"'algo.total_steps' is set by DreamerV3 from learn\(total_timesteps\)"),
        ({"algo.horizon": 2.5}, r"'algo.horizon' must be a whole number \(sheeprl's default is 15\), got 2.5"),
        ({"algo.actor.optimizer.lr": "1e-4"}, r"'algo.actor.optimizer.lr' must be a number .* got '1e-4' \(str\)"),
        ({"algo.world_model": 5}, r"'algo.world_model' must be a dict \(a section\)"),
        ({"fabric.precision": 16}, r"'fabric.precision' is set by DreamerV3 from precision"),
    ],
)
def test_sheeprl_overrides_are_checked_at_construction(overrides, message, tmp_path):
    with pytest.raises(ValueError, match=message):
        DreamerV3("CnnPolicy", toy(), sheeprl_overrides=overrides, work_dir=tmp_path)
