"""Distracting Control: bad names, options and DAVIS folders are refused at make_env with what was expected."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from sb3_ef.envs import make_env
from sb3_ef.envs.distracting import davis
from sb3_ef.envs.distracting.davis import CACHE_FOLDER, DAVIS_TRAIN_VIDEOS, frame_files, load_textures, video_textures
from sb3_ef.envs.distracting.settings import camera_settings, color_settings
from tests.envs.davis_files import FRAMES, write_video

NAME = "dmc-distracting/cartpole-balance"
DOWNLOAD = r"DAVIS-2017-trainval-480p\.zip .*https://davischallenge\.org/davis2017/code\.html.*DAVIS/JPEGImages/480p"


def test_without_a_davis_folder_the_error_says_where_to_get_one(monkeypatch):
    monkeypatch.delenv("SB3_EF_DAVIS_DIR", raising=False)
    with pytest.raises(ValueError, match="'background' distraction plays DAVIS 2017 videos: download " + DOWNLOAD):
        make_env(NAME, size=32)


def test_a_folder_that_does_not_exist(tmp_path):
    missing = re.escape(str(tmp_path / "nope"))
    with pytest.raises(FileNotFoundError, match=f"background_dir '{missing}' is not a folder"):
        make_env(NAME, size=32, background_dir=tmp_path / "nope")


def test_a_folder_without_videos(tmp_path):
    (tmp_path / "notes.txt").write_text("no videos here")
    with pytest.raises(ValueError, match="holds no DAVIS videos .*bear/00000.jpg.*download " + DOWNLOAD):
        make_env(NAME, size=32, background_dir=tmp_path)


def test_a_parent_of_the_480p_folder_is_pointed_to_it(davis_dir):
    davis = davis_dir.parents[1]  # DAVIS/, holding JPEGImages/480p
    with pytest.raises(ValueError, match=f"holds no DAVIS videos.*pass '{re.escape(str(davis_dir))}' instead"):
        make_env(NAME, size=32, background_dir=davis)


def test_a_folder_with_too_few_videos_for_the_difficulty(davis_dir, tmp_path):
    with pytest.raises(ValueError, match=r"lacks 4 of the 8 videos the 'medium' background draws from \(breakdance"):
        make_env(NAME, size=32, background_dir=davis_dir, difficulty="medium")
    with pytest.raises(ValueError, match="lacks 3 of the 4 videos the 'easy' background draws from"):
        make_env(NAME, size=32, background_dir=davis_dir, background_videos="val")
    with pytest.raises(ValueError, match=r"'easy' background difficulty draws from 4 videos, but .* names 2"):
        make_env(NAME, size=32, background_dir=davis_dir, background_videos=["bear", "boat"])
    write_video(tmp_path / DAVIS_TRAIN_VIDEOS[0], np.random.default_rng(0), frames=1)
    (tmp_path / DAVIS_TRAIN_VIDEOS[1]).mkdir()  # a video folder without frames counts as missing
    with pytest.raises(ValueError, match=r"lacks 3 of the 4 videos .*bmx-bumps, boat, boxing-fisheye"):
        make_env(NAME, size=32, background_dir=tmp_path)


def test_an_unreadable_frame_is_named_when_the_env_is_made(tmp_path):
    for video in DAVIS_TRAIN_VIDEOS[:4]:
        (tmp_path / video).mkdir()
        (tmp_path / video / "00000.jpg").write_bytes(b"not a jpeg")
    with pytest.raises(ValueError, match=r"The background frame '.*00000\.jpg' cannot be decoded .*damaged"):
        make_env(NAME, size=32, background_dir=tmp_path, distraction="background")


def damaged_copy(davis_dir: Path, folder: Path) -> Path:
    """A copy of the DAVIS folder whose second video's last frame is cut in half, as a failed copy leaves it."""
    shutil.copytree(davis_dir, folder, ignore=shutil.ignore_patterns(CACHE_FOLDER))
    frame = frame_files(folder / DAVIS_TRAIN_VIDEOS[1])[-1]
    frame.write_bytes(frame.read_bytes()[: frame.stat().st_size // 2])
    return frame


def test_a_damaged_jpeg_among_real_ones_is_named_with_the_remedy(davis_dir, tmp_path):
    frame = damaged_copy(davis_dir, tmp_path / "480p")
    message = (
        f"The background frame '{re.escape(str(frame))}' cannot be decoded \\(.*\\): the file "
        "is damaged; unzip its video folder again from DAVIS-2017-trainval-480p.zip"
    )
    with pytest.raises(ValueError, match=message):
        make_env(NAME, size=32, background_dir=tmp_path / "480p", distraction="background")
    cached = [path.name for path in (tmp_path / "480p" / CACHE_FOLDER).iterdir()]
    assert any(name.startswith("bear-800-") for name in cached)  # the intact video before it (800: DMC's sky)
    assert not any(name.startswith((DAVIS_TRAIN_VIDEOS[1], ".")) for name in cached)  # nothing of the damaged one


def test_videos_are_decoded_once_into_a_cache_until_a_frame_changes(davis_dir, tmp_path, monkeypatch):
    folders = [tmp_path / "480p" / video for video in DAVIS_TRAIN_VIDEOS[:4]]
    shutil.copytree(davis_dir, tmp_path / "480p", ignore=shutil.ignore_patterns(CACHE_FOLDER))
    decoded = load_textures(frame_files(folders[1]), 16, 16)
    opened: list[Path] = []
    original = davis.Image.open
    monkeypatch.setattr(davis.Image, "open", lambda path, *args: (opened.append(path), original(path, *args))[1])
    first = [video_textures(folder, 16) for folder in folders]
    assert len(opened) == 4 * FRAMES and len(list((tmp_path / "480p" / CACHE_FOLDER).glob("*.npy"))) == 4
    again = [video_textures(folder, 16) for folder in folders]  # another env, in this or another process
    assert len(opened) == 4 * FRAMES and all(isinstance(textures, np.memmap) for textures in again)
    np.testing.assert_array_equal(again[1], decoded)
    np.testing.assert_array_equal(first[1], decoded)
    video_textures(folders[1], 32)  # another texture size: decoded for it
    assert len(opened) == 5 * FRAMES
    frame = frame_files(folders[1])[-1]
    frame.write_bytes(frame.read_bytes()[:-100])
    with pytest.raises(ValueError, match="cannot be decoded"):
        video_textures(folders[1], 16)
    assert opened[-1] == frame and len(opened) == 6 * FRAMES  # only the changed folder


def test_a_folder_that_cannot_hold_the_cache_uses_the_users_cache_folder(davis_dir, tmp_path, monkeypatch):
    shutil.copytree(davis_dir, tmp_path / "480p", ignore=shutil.ignore_patterns(CACHE_FOLDER))
    (tmp_path / "480p" / CACHE_FOLDER).write_text("a file where the cache folder would go: it cannot be made")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    textures = video_textures(tmp_path / "480p" / "bear", 16)
    [cached] = (tmp_path / "cache" / "sb3-ef" / "backgrounds").glob("bear-16-*.npy")
    np.testing.assert_array_equal(np.load(cached), textures)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"distraction": "backgrond"}, "Unknown distraction 'backgrond' (did you mean 'background'?)"),
        ({"distraction": ["color", "colour"]}, "Unknown distraction 'colour' (did you mean 'color'?)"),
        ({"distraction": []}, "distraction must be one of 'background', 'camera', 'color' or a non-empty list"),
        ({"distraction": ["color", "color"]}, "distraction names a distraction twice: ['color', 'color']"),
        ({"distraction": "color", "difficulty": "hardd"}, "Unknown difficulty 'hardd' (did you mean 'hard'?)"),
        ({"distraction": "color", "dynamic": "yes"}, "dynamic must be True or False, got 'yes'"),
        ({"distraction": "color", "background_dir": "."}, "background_dir and background_videos are options of the"),
        ({"distraction": "camera", "camera": 1}, "camera 1 ('lookatcart') is mjCAMLIGHT_TARGETBODY: choose another"),
        ({"background_videos": "training"}, "background_videos must be 'train', 'val' or a list of DAVIS video"),
        ({"distraction": "color", "size": 32, "sizes": 3}, "Unknown env option 'sizes' for dmc-distracting/"),
    ],
)
def test_bad_options(options, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        make_env(NAME, **{"size": 32, **options})


def test_domains_outside_the_suite_are_refused_with_the_ones_it_covers():
    with pytest.raises(ValueError, match="defines its distractions for the domains ball_in_cup, cartpole, cheetah"):
        make_env("dmc-distracting/quadruped-walk", size=32)
    with pytest.raises(ValueError, match="did you mean 'dmc-distracting/walker-walk'"):
        make_env("dmc-distracting/walker-wakl", size=32)


def test_the_suite_scales():
    """The reference code's numbers (suite_utils.py): colour delta s, camera angles s*pi/2, zoom -s/2 .. +1.5 s."""
    assert color_settings("hard", dynamic=False).max_delta == pytest.approx(0.3)
    assert color_settings("easy", dynamic=True).step_std == pytest.approx(0.003)
    assert color_settings("easy", dynamic=False).step_std == 0
    hard = camera_settings("walker", "hard", dynamic=True)
    assert hard.horizontal_delta == hard.vertical_delta == hard.roll_delta == pytest.approx(0.15 * np.pi)
    assert (hard.max_zoom_in, hard.max_zoom_out) == pytest.approx((0.15, 0.45))
    assert (hard.velocity_std, hard.max_velocity) == pytest.approx((0.03, 0.12))
    assert (hard.roll_std, hard.max_roll_velocity) == pytest.approx((0.001 * np.pi, 0.006 * np.pi))
    assert hard.upper_quadrant and not camera_settings("reacher", "easy", dynamic=False).upper_quadrant
    assert camera_settings("walker", "easy", dynamic=False).max_velocity == 0
