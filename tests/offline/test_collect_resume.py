"""``collect`` into a folder that already holds episodes: damaged files, other settings, full disks and Ctrl-C."""

from __future__ import annotations

import json
import os
import re

import numpy as np
import pytest

from sb3_ef.cli import main
from sb3_ef.ef.babbling import babble
from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.offline.collect import RECORD, collect, record_episode
from sb3_ef.offline.episodes import read_episode_file
from sb3_ef.offline.readers import FolderDataset
from tests.offline.helpers import interrupt_when, run_with_file_size_limit, sb3_ef_process


def reference_episode(index: int, size: int = 16, seed: int = 0):
    """Episode ``index`` of ``collect(seed=seed)``, recorded directly."""
    env = ToyAgentEnv(size=size, frame_stack=1)
    rng = np.random.default_rng([seed, index])
    return record_episode(env, lambda _observation: babble(rng, (2,)), seed=seed + index)


def test_damaged_or_empty_episode_files_are_recorded_again(tmp_path):
    paths = collect("toy/agent-v0", tmp_path, episodes=3, size=16, progress_bar=False, masks=False)
    good = os.path.getmtime(paths[0])
    open(paths[1], "wb").close()  # what a full disk left before episodes were written atomically
    with open(paths[2], "r+b") as file:
        file.truncate(os.path.getsize(paths[2]) // 2)
    with pytest.warns(UserWarning) as caught:
        again = collect("toy/agent-v0", tmp_path, episodes=3, size=16, progress_bar=False, masks=False)
    messages = sorted(str(warning.message) for warning in caught)
    assert len(messages) == 2, messages
    assert re.search(r"episode_00001.npz: corrupt or truncated .*: recording it again", messages[0])
    assert re.search(r"episode_00002.npz: corrupt or truncated .*: recording it again", messages[1])
    assert again == paths and os.path.getmtime(paths[0]) == good  # the intact one is kept as it was
    for index in (1, 2):
        np.testing.assert_array_equal(read_episode_file(paths[index]).actions, reference_episode(index).actions)


def test_a_rerun_with_another_frame_size_or_seed_is_refused_before_recording(tmp_path):
    collect("toy/agent-v0", tmp_path, episodes=2, size=16, progress_bar=False, masks=False)
    written = sorted(os.listdir(tmp_path))
    with pytest.raises(
        ValueError, match=r"holds a collection with other settings \(--size: 16, not 32; --seed: 0, not 1"
    ):
        collect("toy/agent-v0", tmp_path, episodes=3, size=32, seed=1, progress_bar=False, masks=False)
    os.remove(tmp_path / RECORD)  # a folder of an earlier version, or written by hand: the files themselves are checked
    with pytest.raises(ValueError, match=r"episode_00000.npz: frames \(3, 16, 16\) .* records frames \(3, 32, 32\)"):
        collect("toy/agent-v0", tmp_path, episodes=3, size=32, progress_bar=False, masks=False)
    assert sorted(os.listdir(tmp_path)) == sorted(set(written) - {RECORD})  # the settings file is not rewritten
    assert len(FolderDataset(tmp_path)) == 2  # nothing recorded beside the 16x16 episodes


def test_other_episode_files_in_the_folder_are_named(tmp_path):
    collect("toy/agent-v0", tmp_path, episodes=3, size=16, progress_bar=False, masks=False)
    with pytest.warns(UserWarning, match=r"also holds 1 other episode files \(episode_00002.npz, ...\): readers"):
        paths = collect("toy/agent-v0", tmp_path, episodes=2, size=16, progress_bar=False, masks=False)
    assert len(paths) == 2


def test_a_full_disk_leaves_no_episode_file_and_a_rerun_completes(tmp_path):
    out = tmp_path / "data"
    result = run_with_file_size_limit(
        "from sb3_ef.offline.collect import collect",
        f"collect('toy/agent-v0', {str(out)!r}, episodes=2, size=32, progress_bar=False)",
        limit=1000,  # the settings file fits, an episode file does not
    )
    assert result.returncode != 0 and "File too large" in result.stderr
    assert sorted(os.listdir(out)) == [RECORD]  # no cut episode_00000.npz, no temporary file
    assert main(["collect", "toy/agent-v0", str(out), "--episodes", "2", "--size", "32", "--no-progress"]) == 0
    assert len(FolderDataset(out)) == 2


def test_ctrl_c_keeps_the_finished_episodes_and_a_rerun_records_the_rest(tmp_path):
    out = tmp_path / "data"
    process = sb3_ef_process("collect", "toy/agent-v0", str(out), "--episodes", "400", "--size", "16", "--no-masks")
    status, err = interrupt_when(process, lambda: (out / "episode_00002.npz").exists())
    lines = [line for line in err.splitlines() if line.startswith("sb3-ef collect: interrupted")]
    assert status == 130 and "Traceback" not in err and len(lines) == 1, err
    kept = len(FolderDataset(out))
    assert f"{kept} of 400 episodes are in" in lines[0] and "rerun the command to record the other" in lines[0]
    assert not [name for name in os.listdir(out) if name.startswith(".")]  # the temporary file of the cut episode
    argv = ["collect", "toy/agent-v0", str(out), "--episodes", str(kept + 2), "--size", "16", "--no-masks"]
    assert main([*argv, "--no-progress"]) == 0
    episodes = FolderDataset(out)
    assert len(episodes) == kept + 2
    np.testing.assert_array_equal(episodes[kept + 1].actions, reference_episode(kept + 1).actions)


def test_collect_prints_the_episodes_in_the_folder(tmp_path, capsys):
    argv = ["collect", "toy/agent-v0", str(tmp_path / "d"), "--size", "16", "--no-masks", "--no-progress"]
    assert main([*argv, "--episodes", "2"]) == 0
    assert capsys.readouterr().out.strip() == f"2 episodes in {tmp_path / 'd'} (episode_00000.npz .. episode_00001.npz)"
    assert json.loads((tmp_path / "d" / RECORD).read_text())["size"] == 16
