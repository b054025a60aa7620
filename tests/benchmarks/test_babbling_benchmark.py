"""benchmarks/babbling.py reads the adaptive end off a fixed-babbling run: its replay of the plateau rule must end
where MotorBabblingCallback ends on the same scores."""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

import pytest
from stable_baselines3 import SAC

from sb3_ef import MotorBabblingCallback
from sb3_ef.drqv2.policies import DrQv2Encoder
from sb3_ef.envs.toy import ToyAgentEnv

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "babbling.py"
SCORES = [1.0, 0.9, 0.95, 0.92, 0.8, 0.85, 0.86, 0.87, 0.7, 0.71]
POLICY = {
    "net_arch": [8],
    "normalize_images": False,
    "features_extractor_class": DrQv2Encoder,
    "features_extractor_kwargs": {"features_dim": 16},
}


def load_script():
    spec = importlib.util.spec_from_file_location("babbling_benchmark", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(("min_steps", "patience"), [(10, 2), (60, 2), (70, 3), (10, 5)])
def test_the_replayed_end_is_the_callbacks(min_steps, patience):
    scores = iter(SCORES)
    babbling = MotorBabblingCallback(
        "adaptive",
        min_steps=min_steps,
        max_steps=100,
        patience=patience,
        eval_freq=10,
        criterion=lambda _: next(scores),
    )
    model = SAC(
        "CnnPolicy", ToyAgentEnv(size=32), buffer_size=200, batch_size=4, learning_starts=10, policy_kwargs=POLICY
    )
    model.learn(110, callback=babbling)

    args = argparse.Namespace(patience=patience, min_delta=0.01, min_steps=min_steps, fixed_steps=100)
    replay = [(step, score, 0.0) for step, score in zip(range(10, 110, 10), SCORES, strict=True)]
    assert load_script().adaptive_end(replay, args) == (babbling.end_step, babbling.end_reason)
