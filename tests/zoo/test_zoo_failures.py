"""``sb3-ef train`` when something goes wrong: a run that fails part-way names its last checkpoint and the command
that continues from it (which works), and bad ``--hyperparams`` are one line naming the argument."""

from __future__ import annotations

import pytest

from sb3_ef import cli
from tests.helpers.zoo import ENV_KWARGS, HYPERPARAMS, cli_pairs

ENV_ID = "dmc/cartpole-swingup-v0"


def train_argv(algo: str, log_folder, *extra: str) -> list[str]:
    return [
        "train", "--algo", algo, "--env", ENV_ID, "-f", str(log_folder), "--seed", "0", "--eval-freq", "-1",
        "--num-threads", "1", "--verbose", "0", "--env-kwargs", *cli_pairs(ENV_KWARGS[algo]),
        "--hyperparams", *cli_pairs(HYPERPARAMS[algo]), *extra,
    ]  # fmt: skip


@pytest.fixture(autouse=True)
def _no_traceback(monkeypatch):
    monkeypatch.delenv("SB3_EF_TRACEBACK", raising=False)


def test_a_run_that_fails_part_way_names_its_last_checkpoint_and_how_to_resume(tmp_path, monkeypatch, capsys):
    from sb3_ef.drqv2 import drqv2

    collect = drqv2.DrQv2.collect_rollouts

    def failing_at_step_50(self, *args, **kwargs):
        if self.num_timesteps >= 50:
            raise ValueError("the simulator diverged")
        return collect(self, *args, **kwargs)

    logs = tmp_path / "logs"
    with monkeypatch.context() as patch:
        patch.setattr(drqv2.DrQv2, "collect_rollouts", failing_at_step_50)
        assert cli.main(train_argv("drqv2_ef", logs, "-n", "80", "--save-freq", "20")) == 2
    run = logs / "drqv2_ef" / "dmc-cartpole-swingup-v0_1"
    [line] = capsys.readouterr().err.splitlines()
    assert line == (
        f"sb3-ef train: error: the simulator diverged The run's last checkpoint is {run}/rl_model_40_steps.zip "
        f"(step 40): continue with `sb3-ef train --resume {run}`"
    )
    resume = line.split("`")[1].split()  # the command the note names continues the run
    assert cli.main([*resume[1:], "-n", "60"]) == 0
    assert (run / "dmc-cartpole-swingup-v0.zip").is_file()


def test_an_argument_curl_does_not_take_is_one_line(tmp_path, capsys):
    assert cli.main(train_argv("curl", tmp_path / "logs", "-n", "10", "--hyperparams", "beta:1")) == 2
    [line] = capsys.readouterr().err.splitlines()
    assert line.startswith("sb3-ef train: error: --hyperparams: unknown key 'beta' for curl; expected one of [")
    assert not (tmp_path / "logs").exists()  # refused before the run folder is made


@pytest.mark.parametrize(("algo", "name"), [("curl", "CURL"), ("sac_ef", "SACEF")])
def test_a_bad_ent_coef_names_the_argument(tmp_path, capsys, algo, name):
    assert cli.main(train_argv(algo, tmp_path / "logs", "-n", "10", "--hyperparams", "ent_coef:'bogus'")) == 2
    [line] = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert line == (
        f"sb3-ef train: error: {name}: ent_coef must be a number >= 0 (a fixed entropy coefficient), 'auto' or "
        "'auto_<initial value > 0>' (learned), got str 'bogus'"
    )
