"""Adaptive motor babbling: the plateau rule, ending between min_steps and max_steps on a real EF, and criteria."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from stable_baselines3 import SAC
from stable_baselines3.common.logger import KVWriter, Logger

from sb3_ef import DrQv2EF, MotorBabblingCallback
from sb3_ef.drqv2.policies import DrQv2Encoder
from sb3_ef.ef.babbling import Plateau, foresight_error_ratio, record_held_out_windows
from sb3_ef.envs.toy import AGENT_COLOUR, ToyAgentEnv

EF_POLICY = {
    "net_arch": [16], "trunk_dim": 8, "features_dim": 32, "agent_dim": 8,
    "ef_kwargs": {"rollout_hidden_dims": (16,), "decoder_channels": 8},
}  # fmt: skip
SB3_POLICY = {
    "net_arch": [16],
    "normalize_images": False,
    "features_extractor_class": DrQv2Encoder,
    "features_extractor_kwargs": {"features_dim": 32},
}
EVAL_FREQ = 20


class RecordingWriter(KVWriter):
    def __init__(self):
        self.records: list[dict] = []

    def write(self, key_values, key_excluded, step=0):
        self.records.append(dict(key_values))


def toy_env() -> ToyAgentEnv:
    return ToyAgentEnv(size=32, max_episode_steps=20)


def drqv2_ef(learning_rate: float) -> DrQv2EF:
    return DrQv2EF(
        "CnnPolicy", toy_env(), buffer_size=500, batch_size=16, learning_starts=20, ef_horizon=3, babbling_steps=0,
        learning_rate=learning_rate, policy_kwargs=dict(EF_POLICY), seed=0,
    )  # fmt: skip


def adaptive(**kwargs) -> MotorBabblingCallback:
    arguments = {"eval_freq": EVAL_FREQ, "eval_env": toy_env(), "holdout_steps": 60, "holdout_windows": 16}
    return MotorBabblingCallback("adaptive", **{**arguments, **kwargs})


def test_the_plateau_rule():
    falling = Plateau(patience=2, min_delta=0.01)
    assert not any(falling.update(score) for score in 0.95 ** np.arange(20))
    flat = Plateau(patience=2, min_delta=0.01)
    assert [flat.update(score) for score in (1.0, 1.0, 0.995, 0.99)] == [False, False, True, True]
    assert flat.best == 1.0  # 0.995 and 0.99 are less than 1% below the best: no improvement
    rising_then_falling = Plateau(patience=3, min_delta=0.01)
    assert [rising_then_falling.update(score) for score in (1.0, 1.2, 1.1, 0.9, 0.95)] == [False] * 5


def test_a_frozen_ef_plateaus_and_babbling_ends_at_min_steps():
    """learning_rate=0: EF never improves, so the scores plateau after `patience` evaluations (step 60); babbling
    still goes on to min_steps."""
    model = drqv2_ef(learning_rate=0.0)
    writer = RecordingWriter()
    model.set_logger(Logger(folder=None, output_formats=[writer]))
    babbling = adaptive(min_steps=70, max_steps=200, patience=2)
    model.learn(80, callback=babbling, log_interval=1)
    assert (babbling.end_step, babbling.end_reason) == (70, "plateau")
    assert [step for step, _ in babbling.state.scores] == [20, 40, 60]  # evaluated from learning_starts on
    ended = [record for record in writer.records if "babbling/end_step" in record]
    assert [(record["babbling/end_step"], record["babbling/end_reason"]) for record in ended] == [(70, "plateau")]
    assert any("babbling/score" in record for record in writer.records)


# About 15 s on an idle 2-core machine: slow.
@pytest.mark.slow
def test_a_learning_ef_babbles_while_its_error_falls():
    """With EF learning, the held-out error is flat while the first updates warm EF up (min_steps covers that),
    then falls for several evaluations: babbling goes on while it falls and ends after two evaluations without a
    1% improvement."""
    model = drqv2_ef(learning_rate=1e-3)
    babbling = adaptive(min_steps=100, max_steps=400, patience=2)
    model.learn(300, callback=babbling)
    scores = [score for _, score in babbling.state.scores]
    assert scores[-1] < 0.9 * scores[0]  # EF learned to predict the held-out episodes better
    assert babbling.end_reason == "plateau" and babbling.end_step > 100 + 2 * EVAL_FREQ
    bests = np.minimum.accumulate(scores)
    assert all(scores[i] >= 0.99 * bests[i - 1] for i in (-2, -1))
    assert scores[-3] < 0.99 * bests[-4]  # the evaluation before them improved: the error was still falling
    assert babbling.end_step - babbling.state.scores[-1][0] <= EVAL_FREQ


def test_a_criterion_that_keeps_falling_babbles_to_max_steps_on_a_plain_algorithm():
    model = SAC("CnnPolicy", toy_env(), buffer_size=200, batch_size=4, learning_starts=10, policy_kwargs=SB3_POLICY)
    babbling = MotorBabblingCallback(
        "adaptive", min_steps=0, max_steps=70, patience=1, eval_freq=10, criterion=lambda m: 1 / (1 + m.num_timesteps)
    )
    model.learn(80, callback=babbling)
    assert (babbling.end_step, babbling.end_reason) == (70, "max_steps")
    assert [step for step, _ in babbling.state.scores] == [10, 20, 30, 40, 50, 60]


def test_adaptive_babbling_needs_ef_or_a_criterion():
    model = SAC("CnnPolicy", toy_env(), buffer_size=200, batch_size=4, learning_starts=10, policy_kwargs=SB3_POLICY)
    with pytest.raises(ValueError, match=r"SAC has no EF module: pass criterion="):
        model.learn(10, callback=adaptive(max_steps=50))
    with pytest.raises(ValueError, match=r"expects a finite score >= 0 .*got -1.0"):
        model.learn(30, callback=MotorBabblingCallback("adaptive", max_steps=50, eval_freq=10, criterion=lambda m: -1))


def test_latent_ef_needs_a_criterion():
    policy = {**EF_POLICY, "ef_kwargs": {**EF_POLICY["ef_kwargs"], "target": "latent"}}
    model = DrQv2EF("CnnPolicy", toy_env(), buffer_size=200, batch_size=4, learning_starts=10, ef_horizon=3,
                    babbling_steps=0, policy_kwargs=policy)  # fmt: skip
    with pytest.raises(ValueError, match=r"latent EF .* decodes none while it trains: pass criterion="):
        model.learn(10, callback=adaptive(max_steps=50))


def test_the_held_out_env_must_match_the_model():
    model = drqv2_ef(learning_rate=1e-3)
    with pytest.raises(ValueError, match=r"eval_env observations must have the model's shape \(9, 32, 32\)"):
        model.learn(10, callback=adaptive(max_steps=50, eval_env=ToyAgentEnv(size=64)))


def test_held_out_windows_are_consecutive_babbling_frames_with_their_agent_masks():
    horizon = 3
    windows = record_held_out_windows(
        toy_env(), horizon, steps=50, windows=10, rng=np.random.default_rng(0), mode="sign"
    )
    assert windows.observations.shape == (10, 9, 32, 32) and windows.targets.shape == (10, horizon, 3, 32, 32)
    assert windows.actions.shape == (10, horizon, 2) and np.all(np.abs(windows.actions) == 1.0)
    red = np.array(AGENT_COLOUR, dtype=np.uint8)[:, None, None]
    # The toy agent is the red square, drawn on top: its mask is where the frame is red.
    np.testing.assert_array_equal(windows.masks[:, 1:], np.all(windows.targets == red, axis=2))
    np.testing.assert_array_equal(windows.masks[:, 0], np.all(windows.observations[:, -3:] == red, axis=1))
    # Windows spread over the episodes; one step later, a window's first target is the next context's newest frame.
    again = record_held_out_windows(toy_env(), horizon, steps=50, windows=50, rng=np.random.default_rng(0), mode="sign")
    np.testing.assert_array_equal(again.targets[:10, 0], again.observations[1:11, -3:])


def test_the_agent_pixel_ratio_scores_only_where_the_agent_is():
    model = drqv2_ef(learning_rate=1e-3)
    windows = record_held_out_windows(toy_env(), 3, steps=40, windows=8, rng=np.random.default_rng(0), mode="sign")
    agent, frame = (foresight_error_ratio(model, windows, agent_pixels=flag) for flag in (True, False))
    without_masks = foresight_error_ratio(model, dataclasses.replace(windows, masks=None))
    assert agent > 0 and frame > 0 and agent != frame and without_masks == frame
