import json

import numpy as np
import pytest
from PIL import Image

from sb3_ef import DrQv2EF
from sb3_ef.analysis.cli import main
from sb3_ef.analysis.records import append_records
from sb3_ef.envs.toy import ToyAgentEnv

TINY_DRQV2 = {
    "features_dim": 64,
    "agent_dim": 8,
    "net_arch": [32, 32],
    "trunk_dim": 16,
    "ef_kwargs": {"rollout_hidden_dims": (16,), "decoder_channels": 8},
}


def write_results(directory):
    rng = np.random.default_rng(0)
    for algo, slope in (("DrQv2EF", 2.0), ("DrQv2", 1.0)):
        for seed in (0, 1):
            rows = [
                {"algo": algo, "task": task, "seed": seed, "step": step, "frame": 2 * step,
                 "return": slope * step + rng.uniform(0, 10), "success": ""}
                for task in ("dmc/reacher-easy", "dmc/cartpole-swingup")
                for step in (0, 100, 200, 300)
            ]  # fmt: skip
            append_records(directory / algo / f"seed{seed}.csv", rows)


def test_results_command_writes_tables_and_plots(tmp_path, capsys):
    write_results(tmp_path / "runs")
    assert main(["results", str(tmp_path / "runs"), "--out", str(tmp_path / "out"), "--reps", "20"]) == 0
    out = tmp_path / "out"
    names = {path.name for path in out.iterdir()}
    assert {"scores.csv", "ens.csv", "ens_details.csv", "rliable.csv", "ens.png", "rliable.png"} <= names
    assert {"curve_dmc_reacher-easy.png", "curve_dmc_cartpole-swingup.png"} <= names
    ens = dict(line.split(",") for line in (out / "ens.csv").read_text().splitlines()[1:])
    # the faster learner (slope 2) sets the thresholds and scores about 1; the slower one about half of that
    assert float(ens["DrQv2EF"]) > 0.9 and 0.3 < float(ens["DrQv2"]) < 0.7
    assert "IQM" in capsys.readouterr().out


def test_results_command_without_records_fails_clearly(tmp_path):
    with pytest.raises(FileNotFoundError, match="No evaluation CSV"):
        main(["results", str(tmp_path)])


def test_model_command_writes_prediction_saliency_and_scores(tmp_path):
    model = DrQv2EF("CnnPolicy", ToyAgentEnv(size=32), buffer_size=100, batch_size=4, learning_starts=8,
                    ef_horizon=3, babbling_steps=0, policy_kwargs=TINY_DRQV2, device="cpu")  # fmt: skip
    model.learn(10)
    model.save(tmp_path / "model.zip")
    out = tmp_path / "analysis"
    status = main(["model", str(tmp_path / "model.zip"), "--env", "toy/agent-v0", "--steps", "5",
                   "--actions", "figure8", "--out", str(out)])  # fmt: skip
    assert status == 0
    assert Image.open(out / "prediction.png").size == (5 * 32 + 8, 3 * 32 + 4)
    assert Image.open(out / "saliency.png").size == (3 * 32 + 4, 32)
    assert (out / "prediction.gif").stat().st_size > 0
    scores = json.loads((out / "scores.json").read_text())
    assert scores["steps"] == 5 and {"prediction_mse", "mask_precision", "mask_recall", "mask_iou"} <= set(scores)
    with pytest.raises(SystemExit):
        main(["model", str(tmp_path / "model.zip")])  # --env is required
