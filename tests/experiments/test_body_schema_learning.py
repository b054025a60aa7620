"""The body-schema measures tell an agent from a distractor once EF has learned: on the toy world (a square moved
by the actions, a square on a random walk) a small offline EF predicts the agent's pixels better than copying and
puts more h_a saliency on the agent than on the distractor. And the study's command runs end to end and scores
a saved model again with the same errors."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from body_schema import cut_region_windows, evaluate_regions, window_figure
from scripted import ScriptedEpisode

from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.offline.episodes import make_episode
from sb3_ef.offline.pretrain import pretrain

ROOT = Path(__file__).resolve().parents[2]
MEASURE = ROOT / "experiments" / "2026-12-body-schema" / "measure.py"


def _toy_episodes(count: int, steps: int, seed: int) -> list[ScriptedEpisode]:
    env = ToyAgentEnv(size=32, frame_stack=1, max_episode_steps=steps)
    rng = np.random.default_rng(seed)
    episodes = []
    for index in range(count):
        observation, _ = env.reset(seed=seed * 1000 + index)
        frames, actions, agent, distractor, positions = [observation], [], [env.agent_mask()], [], []
        distractor.append(env.distractor_mask())
        positions.append(env.distractor_position)
        for _ in range(steps):
            action = rng.choice([-1.0, 1.0], 2).astype(np.float32)
            observation, *_ = env.step(action)
            frames.append(observation)
            actions.append(action)
            agent.append(env.agent_mask())
            distractor.append(env.distractor_mask())
            positions.append(env.distractor_position)
        position = np.concatenate([np.stack(positions) / 32, np.zeros((steps + 1, 1))], axis=1)
        episodes.append(
            ScriptedEpisode(
                scenario="toy",
                frames=np.stack(frames),
                actions=np.stack(actions),
                masks={"agent": np.stack(agent), "distractor": np.stack(distractor)},
                hand=np.zeros_like(position),
                object=position,
                attached=np.zeros(steps + 1, bool),
                reset_seed=seed * 1000 + index,
            )
        )
    return episodes


@pytest.mark.slow  # about 8 minutes on 2 busy cores
def test_learned_ef_predicts_the_agent_and_not_the_distractor(tmp_path):
    train = _toy_episodes(24, 30, seed=0)
    model, _ = pretrain(
        [make_episode(e.frames, e.actions) for e in train],
        tmp_path,
        encoder="drqv2",
        context=2,
        horizon=4,
        steps=1500,
        batch_size=16,
        learning_rate=2e-3,
        holdout=0,
        encoder_kwargs={"features_dim": 64},
        ef_kwargs={"decoder_channels": 16, "rollout_hidden_dims": (64, 64)},
        progress_bar=False,
        tensorboard=False,
    )
    windows = cut_region_windows(_toy_episodes(4, 30, seed=1), context=2, horizon=4, stride=2)
    scores = evaluate_regions(model, windows, saliency_windows=16)
    agent, distractor = scores["agent"], scores["distractor"]
    assert agent["ratio"] < 0.8, scores
    assert agent["ratio"] < distractor["ratio"], scores  # 0.59 against 0.72 in one run
    assert agent["saliency_enrichment"] > 1.5 * distractor["saliency_enrichment"], scores  # 3.3 against 1.6
    assert scores["windows"]["count"] == len(windows)
    image = window_figure(model, windows, 0)
    assert image.shape == (4 * 32 + 3 * 2, 4 * 32 + 3 * 2, 3)


@pytest.mark.slow
def test_study_command_writes_results_table_and_figures(tmp_path):
    out = tmp_path / "out"
    command = [sys.executable, str(MEASURE), "run", "--seeds", "0",
               "--experiments", "held-tool", "--size", "32", "--steps", "14", "--train-episodes", "2",
               "--eval-episodes", "1", "--updates", "4", "--saliency-windows", "2", "--context", "2",
               "--horizon", "4", "--out", str(out)]  # fmt: skip
    environment = {**os.environ, "MUJOCO_GL": "egl", "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    subprocess.run(command, check=True, env=environment, capture_output=True, timeout=600)
    runs = json.loads((out / "results.json").read_text())["runs"]
    assert [(run["experiment"], run["seed"]) for run in runs] == [("held-tool", 0)]
    assert set(runs[0]["conditions"]) == {"hammer-held", "hammer-table"}
    assert {"ratio", "saliency_enrichment"} <= set(runs[0]["conditions"]["hammer-held"]["hammer"])
    table = (out / "table.md").read_text()
    assert "| held-tool | hammer-held | 1 |" in table and "| held-tool | hammer-table | 1 |" in table
    assert sorted(os.listdir(out / "figures")) == ["figure8_s0.png", "hammer-held_s0.png", "hammer-table_s0.png"]
    combined = subprocess.run(
        [sys.executable, str(MEASURE), "table", str(out)],
        check=True, env=environment, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert combined.stdout == table
    # Scoring the saved model again re-collects the held-out episodes: the same errors to the last digit.
    subprocess.run([*command, "--rescore"], check=True, env=environment, capture_output=True, timeout=600)
    rescored = json.loads((out / "results.json").read_text())["runs"]
    assert len(rescored) == 1 and "train_seconds" in rescored[0]
    for condition in ("hammer-held", "hammer-table"):
        for region in ("hammer", "agent", "frame"):
            first, again = runs[0]["conditions"][condition][region], rescored[0]["conditions"][condition][region]
            assert again["model_mse"] == first["model_mse"] and again["copy_mse"] == first["copy_mse"]
