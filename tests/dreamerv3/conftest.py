"""One tiny DreamerV3 trained once for the tests that read it (save, load and predict them on a copy or as it is)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from stable_baselines3.common.callbacks import (
    CallbackList,
    CheckpointCallback,
    EvalCallback,
    EveryNTimesteps,
    LogEveryNTimesteps,
    StopTrainingOnMaxEpisodes,
    StopTrainingOnNoModelImprovement,
    StopTrainingOnRewardThreshold,
)

from tests.dreamerv3.dreamerv3_tiny import Recorder, tiny, toy


@pytest.fixture(scope="session")
def trained(tmp_path_factory) -> SimpleNamespace:
    """SB3's ``test_callbacks`` on the tiny model: ``learn(40)`` with SB3's callbacks, stopped by
    ``StopTrainingOnMaxEpisodes`` at the end of the first 25-step episode; then 4 steps each with no callback, with
    a list and the progress bar, and with a function (37 steps in all)."""
    pytest.importorskip("sheeprl")
    folder = tmp_path_factory.mktemp("dreamerv3")
    logs = folder / "logs"
    model = tiny(folder / "run")
    checkpoint = CheckpointCallback(save_freq=10, save_path=str(logs))
    evaluation = EvalCallback(
        toy(),
        callback_on_new_best=StopTrainingOnRewardThreshold(reward_threshold=0),  # returns are < 0: never stops
        callback_after_eval=StopTrainingOnNoModelImprovement(max_no_improvement_evals=10, min_evals=1),
        best_model_save_path=str(logs), log_path=str(logs), eval_freq=10, n_eval_episodes=1, warn=False,
    )  # fmt: skip
    on_event = CheckpointCallback(save_freq=1, save_path=str(logs), name_prefix="event")
    event = EveryNTimesteps(n_steps=10, callback=on_event)
    max_episodes = StopTrainingOnMaxEpisodes(max_episodes=1)
    recorder = Recorder()
    callback = CallbackList([checkpoint, evaluation, event, LogEveryNTimesteps(n_steps=10), max_episodes, recorder])
    model.learn(40, callback=callback)
    first = {"steps": model.num_timesteps, "event_steps": event.num_timesteps, "event_calls": event.n_calls}
    model.learn(4, callback=None, reset_num_timesteps=False)
    model.learn(4, callback=[checkpoint, evaluation, recorder], progress_bar=True, reset_num_timesteps=False)
    model.learn(4, callback=lambda _locals, _globals: True, reset_num_timesteps=False)
    return SimpleNamespace(
        model=model, folder=folder, logs=logs, callback=callback, checkpoint=checkpoint, on_event=on_event,
        event=event, max_episodes=max_episodes, recorder=recorder, first=first,
    )  # fmt: skip
