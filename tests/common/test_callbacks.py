import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import TD3
from stable_baselines3.common.callbacks import CheckpointCallback
from stable_baselines3.common.logger import KVWriter, Logger

from sb3_ef.common.callbacks import ActionOverrideMixin, MotorBabblingCallback


class ActionRecordingEnv(gym.Env):
    """A 5-step vector env that records the actions it receives."""

    observation_space = gym.spaces.Box(-1, 1, (3,), np.float32)
    action_space = gym.spaces.Box(-1, 1, (2,), np.float32)

    def __init__(self):
        self.actions: list[np.ndarray] = []
        self._t = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self._t = 0
        return self.observation_space.sample(), {}

    def step(self, action):
        self.actions.append(np.array(action))
        self._t += 1
        return self.observation_space.sample(), 0.0, False, self._t >= 5, {}


class BabblingTD3(ActionOverrideMixin, TD3):
    """TD3 with the babbling hook, as the EF algorithms wire it."""

    def _sample_action(self, learning_starts, action_noise=None, n_envs=1):
        actions = self._override_actions(n_envs)
        if actions is not None:
            return actions, actions
        return super()._sample_action(learning_starts, action_noise, n_envs)


class RecordingWriter(KVWriter):
    def __init__(self):
        self.records: list[dict] = []

    def write(self, key_values, key_excluded, step=0):
        self.records.append(dict(key_values))


def make_model(seed=0, learning_starts=10**6, algorithm=BabblingTD3):
    return algorithm(
        "MlpPolicy", ActionRecordingEnv(), learning_starts=learning_starts, gradient_steps=0,
        policy_kwargs={"net_arch": [8]}, seed=seed, device="cpu",
    )  # fmt: skip


def recorded_actions(model) -> np.ndarray:
    return np.array(model.get_env().envs[0].unwrapped.actions)


@pytest.mark.parametrize("learning_starts", [0, 10**6])
def test_babbles_sign_actions_then_hands_back_to_the_algorithm(learning_starts):
    model = make_model(learning_starts=learning_starts)
    model.learn(30, callback=MotorBabblingCallback(12))
    actions = recorded_actions(model)
    assert np.all(np.abs(actions[:12]) == 1)
    assert np.any(actions[:12] == 1) and np.any(actions[:12] == -1)
    assert np.all(np.abs(actions[12:]) < 1)  # warm-up (uniform) or policy actions are not +-1
    assert model.action_override is None


def test_clamped_uniform_mode_saturates_about_three_quarters():
    model = make_model()
    model.learn(400, callback=MotorBabblingCallback(400, mode="clamped_uniform"))
    actions = recorded_actions(model)
    assert np.all(np.abs(actions) <= 1)
    assert 0.7 < np.mean(np.abs(actions) == 1) < 0.8


def test_seeded_runs_babble_identically():
    runs = []
    for seed in (3, 3, 4):
        model = make_model(seed=seed)
        model.learn(10, callback=MotorBabblingCallback(10))
        runs.append(recorded_actions(model))
    np.testing.assert_array_equal(runs[0], runs[1])
    assert not np.array_equal(runs[0], runs[2])


def test_logs_babbling_flag():
    model = make_model()
    writer = RecordingWriter()
    model.set_logger(Logger(folder=None, output_formats=[writer]))
    model.learn(20, callback=MotorBabblingCallback(10), log_interval=1)
    flags = [record["rollout/babbling"] for record in writer.records]
    assert flags == [1.0, 1.0, 0.0, 0.0]


def test_no_babbling_when_already_past_the_babbling_steps():
    model = make_model()
    model.learn(10, callback=MotorBabblingCallback(10))
    model.learn(10, callback=MotorBabblingCallback(10), reset_num_timesteps=False)
    assert np.all(np.abs(recorded_actions(model)[10:]) < 1)


def test_model_without_the_hook_is_rejected():
    with pytest.raises(TypeError, match="ActionOverrideMixin"):
        make_model(algorithm=TD3).learn(5, callback=MotorBabblingCallback(5))


def test_bad_callback_arguments_are_rejected():
    with pytest.raises(ValueError, match="babbling_steps"):
        MotorBabblingCallback(-1)
    with pytest.raises(ValueError, match="'gaussian'"):
        MotorBabblingCallback(10, mode="gaussian")


def test_hook_checks_what_the_override_returns():
    model = make_model()
    model.action_override = lambda n_envs: np.zeros((n_envs, 3))
    with pytest.raises(ValueError, match=r"\(1, 2\)"):
        model._override_actions(1)
    model.action_override = lambda n_envs: np.full((n_envs, 2), 2.0)
    with pytest.raises(ValueError, match=r"\[-1, 1\]"):
        model._override_actions(1)
    model.action_override = None
    assert model._override_actions(1) is None


def test_models_saved_while_babbling_load_without_the_hook(tmp_path):
    model = make_model()
    checkpoint = CheckpointCallback(save_freq=5, save_path=str(tmp_path), name_prefix="babbling")
    model.learn(5, callback=[MotorBabblingCallback(10), checkpoint])
    assert "action_override" in model._excluded_save_params() and "policy" in model._excluded_save_params()
    loaded = BabblingTD3.load(tmp_path / "babbling_5_steps.zip", env=ActionRecordingEnv())
    assert loaded.action_override is None and loaded._override_actions(1) is None
