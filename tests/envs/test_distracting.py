"""Distracting Control envs on real dm-control tasks and a tiny real DAVIS folder (tests/envs/conftest.py): what
each distraction changes, agent masks under it, static vs dynamic, per-episode draws, seeds and resume."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from stable_baselines3.common.env_checker import check_env

from sb3_ef.envs import make_env
from sb3_ef.envs.agent_geoms import agent_geoms
from sb3_ef.envs.distracting.davis import DAVIS_TRAIN_VIDEOS, frame_files, load_textures
from sb3_ef.envs.pixel_env import AGENT_MASKS_INFO_KEY

SIZE = 48
TASK = "cartpole-balance"


def distracting(davis_dir, distraction, task: str = TASK, **kwargs) -> gym.Env:
    if "background" in distraction:
        kwargs.setdefault("background_dir", davis_dir)
    kwargs.setdefault("seed", 0)
    return make_env(f"dmc-distracting/{task}", size=SIZE, fast_render=True, distraction=distraction, **kwargs)


def actions(env: gym.Env, count: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.uniform(-1, 1, env.action_space.shape).astype(np.float32) for _ in range(count)]


def play(env: gym.Env, steps: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The newest frames and agent masks of a reset with ``seed`` and ``steps`` seeded random actions."""
    obs, _ = env.reset(seed=seed)
    frames, masks = [obs[-3:]], [env.unwrapped.agent_mask()]
    for action in actions(env, steps):
        frames.append(env.step(action)[0][-3:])
        masks.append(env.unwrapped.agent_mask())
    return np.stack(frames), np.stack(masks)


def sky(env: gym.Env) -> np.ndarray:
    """The skybox texture the renderer shows (one square face)."""
    model = env.unwrapped.mujoco_state[0]
    texture = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXTURE, "skybox")
    side, start = int(model.tex_width[texture]), int(model.tex_adr[texture])
    assert model.tex_height[texture] == side
    return model.tex_data[start : start + side * side * 3].copy()


def video_textures(davis_dir, env: gym.Env) -> dict[str, np.ndarray]:
    side = int(env.unwrapped.mujoco_state[0].tex_width[0])
    return {video: load_textures(frame_files(davis_dir / video), side, side) for video in DAVIS_TRAIN_VIDEOS[:4]}


def shown_frame(textures: dict[str, np.ndarray], texture: np.ndarray) -> tuple[str, int]:
    matches = [
        (video, index)
        for video, frames in textures.items()
        for index, frame in enumerate(frames)
        if (frame == texture).all()
    ]
    assert len(matches) == 1, "the sky must show exactly one frame of the easy difficulty's videos"
    return matches[0]


@pytest.mark.parametrize("distraction", ["background", "color"])
def test_the_frame_changes_and_the_agent_mask_stays_the_undistracted_one(davis_dir, distraction):
    plain = make_env(f"dmc/{TASK}", size=SIZE, fast_render=True, seed=0)
    env = distracting(davis_dir, distraction, dynamic=True)
    try:
        plain_frames, plain_masks = play(plain, 4)
        frames, masks = play(env, 4)  # the same initial state and actions: the same simulation
        np.testing.assert_array_equal(masks, plain_masks)
        assert masks[-1].sum() > 10
        difference = np.abs(frames.astype(int) - plain_frames).mean(axis=1)  # (steps, h, w)
        if distraction == "background":  # the sky and the see-through floor, never the agent
            assert difference[~masks].mean() > 20
            assert difference[masks].max() == 0
        else:  # the agent's materials (and the floor's), not the sky
            assert difference[masks].mean() > 3
    finally:
        plain.close()
        env.close()


@pytest.mark.parametrize("task", [TASK, "walker-walk", "reacher-easy"])  # fixed, tracking, top-down (with roll)
def test_camera_distraction_moves_the_view_and_the_mask_with_it(davis_dir, task):
    plain = make_env(f"dmc/{task}", size=SIZE, fast_render=True, seed=0)
    env = distracting(davis_dir, "camera", task, difficulty="hard", dynamic=True)
    renderer = None
    try:
        _, plain_masks = play(plain, 3)
        frames, masks = play(env, 3)
        assert not np.array_equal(masks[-1], plain_masks[-1]), "the camera should have moved"
        # Render the same state from the moved camera with and without the agent: the pixels that change are the
        # agent's, and the env's mask must be exactly those.
        model, data = env.unwrapped.mujoco_state
        renderer = mujoco.Renderer(model, SIZE, SIZE)
        for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION):
            renderer.scene.flags[flag] = False
        renderer.update_scene(data, camera=env.unwrapped.camera)
        with_agent = renderer.render().copy()
        np.testing.assert_array_equal(with_agent.transpose(2, 0, 1), frames[-1])
        hidden = mujoco.MjvOption()
        hidden.geomgroup[:] = 1
        groups = model.geom_group.copy()
        model.geom_group[agent_geoms(model)] = 5
        hidden.geomgroup[5] = 0
        renderer.update_scene(data, camera=env.unwrapped.camera, scene_option=hidden)
        without_agent = renderer.render().copy()
        model.geom_group[:] = groups
        agent_pixels = (with_agent != without_agent).any(axis=-1)
        assert agent_pixels.sum() > 10
        np.testing.assert_array_equal(masks[-1], agent_pixels)
    finally:
        if renderer is not None:
            renderer.close()
        plain.close()
        env.close()


def test_static_background_shows_one_frame_and_dynamic_plays_back_and_forth(davis_dir):
    static = distracting(davis_dir, "background", action_repeat=1)
    dynamic = distracting(davis_dir, "background", action_repeat=1, dynamic=True)
    try:
        textures = video_textures(davis_dir, static)
        play(static, 0)
        first = shown_frame(textures, sky(static))
        for action in actions(static, 5):
            static.step(action)
            assert shown_frame(textures, sky(static)) == first
        play(dynamic, 0)
        shown = [shown_frame(textures, sky(dynamic))]
        for action in actions(dynamic, 12):
            dynamic.step(action)
            shown.append(shown_frame(textures, sky(dynamic)))
        assert len({video for video, _ in shown}) == 1, "one video per episode"
        indices = [index for _, index in shown]

        def bounce(index: int, direction: int) -> list[int]:  # the suite's rule, on 4-frame videos
            sequence = [index]
            for _ in range(12):
                index += direction
                if index <= 0:
                    index, direction = 0, 1
                if index >= 4:
                    index, direction = 3, -1
                sequence.append(index)
            return sequence

        assert indices in (bounce(indices[0], 1), bounce(indices[0], -1))
        assert set(indices) == {0, 1, 2, 3}
    finally:
        static.close()
        dynamic.close()


def test_fast_render_draws_the_sky_at_four_texels_per_pixel_and_otherwise_at_the_models_size(davis_dir):
    fast = distracting(davis_dir, "background")
    full = make_env(f"dmc-distracting/{TASK}", size=SIZE, background_dir=davis_dir, distraction="background", seed=0)
    try:
        for env, side in ((fast, 4 * SIZE), (full, 800)):  # 800: DMC's skybox face
            play(env, 1)
            model = env.unwrapped.mujoco_state[0]
            assert model.tex_width[0] == model.tex_height[0] == side
            shown_frame(video_textures(davis_dir, env), sky(env))  # a frame of the videos, at that size
    finally:
        fast.close()
        full.close()


def test_the_smaller_sky_draws_the_frames_the_full_size_one_does(davis_dir, monkeypatch):
    small = distracting(davis_dir, "background", dynamic=True)
    monkeypatch.setattr("sb3_ef.envs.distracting.env.FAST_TEXELS_PER_PIXEL", 100)  # capped: the model's 800
    large = distracting(davis_dir, "background", dynamic=True)
    try:
        assert large.unwrapped.mujoco_state[0].tex_width[0] == 800
        difference = np.abs(play(small, 3)[0].astype(int) - play(large, 3)[0].astype(int))
        assert difference.mean() < 1.0  # of 255: texture sampling only
    finally:
        small.close()
        large.close()


def test_color_stays_in_the_difficulty_range_and_drifts_only_when_dynamic(davis_dir):
    plain = make_env(f"dmc/{TASK}", size=SIZE)
    original = plain.unwrapped.mujoco_state[0].mat_rgba.copy()
    plain.close()
    for difficulty, scale in (("easy", 0.1), ("hard", 0.3)):
        for dynamic in (False, True):
            env = distracting(davis_dir, "color", difficulty=difficulty, dynamic=dynamic)
            try:
                model = env.unwrapped.mujoco_state[0]
                env.reset(seed=2)
                colors = [model.mat_rgba.copy()]
                for action in actions(env, 4):
                    env.step(action)
                    colors.append(model.mat_rgba.copy())
                colors = np.stack(colors)
                assert np.abs(colors[..., :3] - original[:, :3]).max() <= scale + 1e-6
                assert np.abs(colors[0, :, :3] - original[:, :3]).max() > scale / 2, "a draw, not the original"
                assert np.array_equal(colors[..., 3], np.broadcast_to(original[:, 3], colors[..., 3].shape))
                assert (np.abs(np.diff(colors, axis=0)).max() > 0) == dynamic
            finally:
                env.close()


@pytest.mark.parametrize("dynamic", [False, True])
def test_a_fixed_camera_holds_its_drawn_pose_unless_dynamic(davis_dir, dynamic):
    env = distracting(davis_dir, "camera", difficulty="medium", dynamic=dynamic)
    plain = make_env(f"dmc/{TASK}", size=SIZE, seed=0)
    try:
        data, camera = env.unwrapped.mujoco_state[1], env.unwrapped.camera
        plain.reset(seed=2)
        own = plain.unwrapped.mujoco_state[1].cam_xpos[camera].copy()
        env.reset(seed=2)
        poses = [data.cam_xpos[camera].copy()]
        for action in actions(env, 4):
            env.step(action)
            poses.append(data.cam_xpos[camera].copy())
        assert np.linalg.norm(poses[0] - own) > 1e-3
        # within the medium range: distance -10% .. +30% of the camera's own
        assert 0.9 - 1e-9 <= np.linalg.norm(poses[0]) / np.linalg.norm(own) <= 1.3 + 1e-9
        assert (np.abs(np.diff(poses, axis=0)).max() > 1e-6) == dynamic
    finally:
        env.close()
        plain.close()


def test_same_seed_same_frames_and_each_episode_draws_anew(davis_dir):
    every = ["background", "camera", "color"]
    first, second, other = (distracting(davis_dir, every, dynamic=True, seed=seed) for seed in (3, 3, 4))
    try:
        frames, masks = play(first, 5, seed=None)
        again, again_masks = play(second, 5, seed=None)
        np.testing.assert_array_equal(frames, again)
        np.testing.assert_array_equal(masks, again_masks)
        assert not np.array_equal(play(other, 5, seed=None)[0], frames)
        model, data = first.unwrapped.mujoco_state
        colors, camera = model.mat_rgba.copy(), data.cam_xpos[first.unwrapped.camera].copy()
        first.reset()
        assert np.abs(model.mat_rgba - colors).max() > 0.01, "a new episode draws new colours"
        assert np.abs(data.cam_xpos[first.unwrapped.camera] - camera).max() > 1e-3, "and a new camera pose"
        np.testing.assert_array_equal(play(first, 5, seed=7)[0], play(second, 5, seed=7)[0])
    finally:
        for env in (first, second, other):
            env.close()


def test_the_env_generator_alone_decides_an_episode_so_a_resumed_run_repeats_it(davis_dir):
    """What sb3-ef's checkpoints rely on: an env given another env's np_random state plays that env's episode."""
    every = ["background", "camera", "color"]
    env, resumed = distracting(davis_dir, every, dynamic=True, seed=5), distracting(davis_dir, every, dynamic=True)
    try:
        play(env, 3, seed=None)
        state = env.unwrapped.np_random.bit_generator.state
        expected = play(env, 6, seed=None)
        resumed.unwrapped.np_random.bit_generator.state = state
        np.testing.assert_array_equal(play(resumed, 6, seed=None)[0], expected[0])
    finally:
        env.close()
        resumed.close()


def test_gym_make_spec_masks_in_infos_and_sb3_env_checker(davis_dir):
    env = gym.make(
        f"dmc-distracting/{TASK}-v0", size=SIZE, fast_render=True, background_dir=davis_dir, agent_masks=True
    )
    try:
        assert env.spec.id == f"dmc-distracting/{TASK}-v0"
        assert env.unwrapped.distractions == ("background", "camera", "color")  # all three by default
        _obs, info = env.reset(seed=0)
        assert info[AGENT_MASKS_INFO_KEY].shape == (3, SIZE, SIZE)
        np.testing.assert_array_equal(info[AGENT_MASKS_INFO_KEY][-1], env.unwrapped.agent_mask())
        check_env(env.unwrapped, warn=True, skip_render_check=False)  # closes and reopens the renderer
        again = gym.make(env.unwrapped.spec)
        np.testing.assert_array_equal(again.reset(seed=0)[0], env.reset(seed=0)[0])
        again.close()
    finally:
        env.close()


def test_validation_videos_and_the_davis_dir_variable(davis_dir, monkeypatch):
    monkeypatch.setenv("SB3_EF_DAVIS_DIR", str(davis_dir))
    # 'hard' draws from all the videos named (easy and medium: the first 4 or 8)
    env = distracting(
        davis_dir, "background", background_dir=None, background_videos=["bike-packing"], difficulty="hard"
    )
    try:
        env.reset(seed=0)
        side = int(env.unwrapped.mujoco_state[0].tex_width[0])
        frames = load_textures(frame_files(davis_dir / "bike-packing"), side, side)
        assert any((frame == sky(env)).all() for frame in frames)
    finally:
        env.close()
