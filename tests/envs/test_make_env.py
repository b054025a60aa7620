"""make_env: spaces, frame stack, action repeat, time limits, agent masks, errors, gymnasium and SB3 use."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.env_checker import check_env
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_ef.envs import make_env
from sb3_ef.envs.dmc import DMCPixelEnv
from sb3_ef.envs.meta_world import MetaWorldPixelEnv

SIZE = 64
FIVE_ENVS = ["dmc/cartpole-swingup", "dmc/reacher-easy", "dmc/walker-walk", "metaworld/door-open", "metaworld/hammer"]
ACTION_DIMS = {"dmc/cartpole-swingup": 1, "dmc/reacher-easy": 2, "dmc/walker-walk": 6}


@pytest.fixture(scope="module", params=FIVE_ENVS)
def env(request):
    """Each of the five test envs, built once for the module."""
    environment = make_env(request.param, size=SIZE, seed=0)
    yield environment
    environment.close()


@pytest.fixture(scope="module")
def cartpole():
    environment = make_env("dmc/cartpole-swingup", size=32, seed=0)
    yield environment
    environment.close()


def test_spaces_and_first_observation(env):
    frame_shape = (3 * 3, SIZE, SIZE)
    assert env.observation_space == gym.spaces.Box(0, 255, frame_shape, np.uint8)
    assert env.action_space.dtype == np.float32
    assert np.all(env.action_space.low == -1) and np.all(env.action_space.high == 1)
    if isinstance(env, DMCPixelEnv):
        assert env.action_space.shape == (ACTION_DIMS[f"dmc/{env.task}"],)
    else:
        assert env.action_space.shape == (4,)
    obs, _ = env.reset(seed=1)
    assert obs.shape == frame_shape and obs.dtype == np.uint8
    assert env.observation_space.contains(obs)
    assert obs.std() > 5, "the frame should show a scene, not a constant image"


def test_stack_is_oldest_first_and_repeated_at_reset(cartpole):
    obs, _ = cartpole.reset(seed=2)
    assert np.array_equal(obs[0:3], obs[3:6]) and np.array_equal(obs[3:6], obs[6:9])
    previous = obs
    for _ in range(3):
        obs, *_ = cartpole.step(np.ones(1, np.float32))
        assert np.array_equal(obs[:6], previous[3:]), "older frames must shift towards the front"
        assert not np.array_equal(obs[6:], previous[6:]), "the newest frame must be last"
        previous = obs


def test_action_repeat_sums_rewards_and_renders_once_per_agent_step():
    actions = [np.array([a], np.float32) for a in (1.0, -0.5, 0.8)]
    repeat_two = make_env("dmc/cartpole-swingup", size=32, action_repeat=2, seed=5)
    repeat_one = make_env("dmc/cartpole-swingup", size=32, action_repeat=1, seed=5)
    try:
        assert np.array_equal(repeat_two.reset()[0], repeat_one.reset()[0])
        for action in actions:
            obs, reward, *_ = repeat_two.step(action)
            single = [repeat_one.step(action) for _ in range(2)]
            assert reward == pytest.approx(sum(step[1] for step in single))
            assert np.array_equal(obs[-3:], single[-1][0][-3:])
        assert reward != 0
    finally:
        repeat_two.close()
        repeat_one.close()


@pytest.mark.parametrize("episode_length, truncating_step", [(6, 3), (5, 3)])
def test_time_limit_is_truncation_after_episode_length_sim_steps(cartpole, episode_length, truncating_step):
    cartpole.episode_length = episode_length
    try:
        cartpole.reset(seed=0)
        for step in range(1, truncating_step + 1):
            _, _, terminated, truncated, _ = cartpole.step(np.zeros(1, np.float32))
            assert not terminated
            assert truncated == (step == truncating_step)
        with pytest.raises(RuntimeError, match="reset"):
            cartpole.step(np.zeros(1, np.float32))
    finally:
        cartpole.episode_length = 1000


@pytest.mark.parametrize("name, agent_steps", [("dmc/cartpole-swingup", 500), ("metaworld/door-open", 250)])
def test_full_episode_is_truncated_at_the_suite_length(name, agent_steps):
    environment = make_env(name, size=32, fast_render=True, seed=0)
    try:
        environment.reset()
        action = np.zeros(environment.action_space.shape, np.float32)
        ends = [environment.step(action)[2:4] for _ in range(agent_steps)]
        assert ends[-1] == (False, True)
        assert not any(terminated or truncated for terminated, truncated in ends[:-1])
    finally:
        environment.close()


def test_default_episode_lengths_follow_the_suites(env):
    assert env.episode_length == (1000 if isinstance(env, DMCPixelEnv) else 500)
    assert env.action_repeat == 2


def test_success_flag_is_a_bool_where_the_suite_has_one(env):
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(env.action_space.shape, np.float32))
    if isinstance(env, MetaWorldPixelEnv):
        assert isinstance(info["is_success"], bool)
    else:
        assert "is_success" not in info


def test_metaworld_task_variant_fixed_by_seed_or_resampled():
    environment = make_env("metaworld/door-open", size=32, seed=7)
    try:
        first = environment.reset()[0]
        assert np.array_equal(environment.reset()[0], first), "same variant at every reset by default"
        environment.resample_task = True
        assert not np.array_equal(environment.reset()[0], first), "resample_task draws a new variant"
        environment.resample_task = False
        assert np.array_equal(environment.reset(seed=7)[0], first), "the seed fixes the variant"
    finally:
        environment.close()


def test_agent_mask_is_aligned_with_the_frame_and_moves(env):
    obs, _ = env.reset(seed=3)
    before = env.agent_mask()
    assert before.shape == (SIZE, SIZE) and before.dtype == bool
    assert 0 < before.sum() < before.size / 2
    # The agents (beige DMC bodies, red Sawyer) are redder than their bluish/grey surroundings: a mask that is
    # flipped or shifted against the frame would not pick out the red pixels.
    frame = obs[-3:].astype(float)
    redness = frame[0] - frame[2]
    assert redness[before].mean() > redness[~before].mean() + 30
    action = np.ones(env.action_space.shape, np.float32)
    for _ in range(5):
        env.step(action)
    after = env.agent_mask()
    assert (before != after).sum() > 10, "large actions must move the agent's pixels"


def test_fast_render_frames_stay_close_to_default():
    # Shadows, reflections and multisampling off change shading a little; a broken framebuffer would not.
    for name in ("dmc/cartpole-swingup", "metaworld/door-open"):
        default = make_env(name, size=32, seed=4)
        fast = make_env(name, size=32, seed=4, fast_render=True)
        try:
            default.reset()
            fast.reset()
            action = np.ones(default.action_space.shape, np.float32)
            frames = [environment.step(action)[0].astype(int) for environment in (default, fast)]
            difference = np.abs(frames[0] - frames[1]).mean()
            assert difference < 10, f"{name}: fast frames differ by {difference:.1f} grey levels on average"
        finally:
            default.close()
            fast.close()


def test_seeds_reproduce_initial_states():
    first, other = (make_env("dmc/reacher-easy", size=32, seed=seed) for seed in (1, 2))
    try:
        obs = first.reset()[0]
        assert not np.array_equal(other.reset()[0], obs)
        assert np.array_equal(other.reset(seed=1)[0], obs), "reset(seed) re-seeds like the constructor's seed"
    finally:
        first.close()
        other.close()


def test_render_returns_newest_frame():
    environment = make_env("dmc/cartpole-swingup", size=32, render_mode="rgb_array")
    try:
        environment.reset()
        obs, *_ = environment.step(np.ones(1, np.float32))
        assert np.array_equal(environment.render(), obs[-3:].transpose(1, 2, 0))
        assert environment.metadata["render_fps"] == 50, "cartpole: 0.01 s per simulator step, 2 per agent step"
    finally:
        environment.close()


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"name": "dmc/cartpole-swingup-v1"}, "did you mean 'dmc/cartpole-swingup'"),
        ({"name": "cartpole-swingup"}, "Unknown env name"),
        ({"name": "metaworld/door-open-v3"}, "metaworld/door-open"),
        ({"name": "dmc/cartpole-swingup", "size": 16}, r"\[32, 512\].*got 16"),
        ({"name": "dmc/cartpole-swingup", "size": 84.0}, "got 84.0"),
        ({"name": "dmc/cartpole-swingup", "size": 32, "camera": 7}, r"cameras are 0 \('fixed'\), 1 \('lookatcart'\)"),
        ({"name": "dmc/cartpole-swingup", "size": 32, "camera": "side"}, "Unknown camera 'side'"),
        ({"name": "dmc/cartpole-swingup", "size": 32, "frame_stack": 0}, "frame_stack must be an int >= 1, got 0"),
        ({"name": "dmc/cartpole-swingup", "size": 32, "render_mode": "human"}, "got 'human'"),
    ],
)
def test_bad_arguments_raise_clear_errors(kwargs, message):
    with pytest.raises(ValueError, match=message):
        make_env(**kwargs)


def test_bad_action_shape_raises(cartpole):
    cartpole.reset()
    with pytest.raises(ValueError, match=r"shape \(1,\), got shape \(2,\)"):
        cartpole.step(np.zeros(2, np.float32))


def test_named_cameras_and_v0_suffix():
    environment = make_env("dmc/cartpole-swingup-v0", size=32, camera="lookatcart")
    try:
        assert environment.camera == 1
    finally:
        environment.close()


def test_gym_make_and_sb3_vec_env():
    environment = gym.make("dmc/cartpole-swingup-v0", size=SIZE)
    try:
        assert environment.reset(seed=0)[0].shape == (9, SIZE, SIZE)
        assert hasattr(environment.unwrapped, "agent_mask")
        check_env(environment.unwrapped)
    finally:
        environment.close()
    vec_env = DummyVecEnv([lambda rank=rank: make_env("dmc/reacher-easy", size=32, seed=rank) for rank in range(2)])
    try:
        obs = vec_env.reset()
        assert obs.shape == (2, 9, 32, 32) and obs.dtype == np.uint8
        obs, rewards, _, _ = vec_env.step(np.zeros((2, 2), np.float32))
        assert obs.shape == (2, 9, 32, 32) and rewards.shape == (2,)
    finally:
        vec_env.close()


def test_envs_can_be_created_and_closed_many_times():
    for seed in range(3):
        environment = make_env("dmc/cartpole-swingup", size=32, seed=seed)
        environment.reset()
        environment.step(np.zeros(1, np.float32))
        environment.close()
        environment.close()


@pytest.mark.parametrize(
    ("task", "options"), [("dmc/cartpole-balance", {}), ("metaworld/door-open", {"resample_task": True})]
)
def test_the_envs_own_generator_decides_every_episode(task, options):
    """A checkpoint records ``np_random``: an env given that generator's state plays the same next episode, whatever
    its simulator's generator went through before (here: another seed)."""
    first, second = (make_env(task, size=32, fast_render=True, seed=seed, **options) for seed in (0, 1))
    try:
        first.reset()
        second.reset()
        state = first.np_random.bit_generator.state
        episode = first.reset()[0]
        assert not np.array_equal(second.reset()[0], episode)
        second.np_random.bit_generator.state = state
        assert np.array_equal(second.reset()[0], episode)
    finally:
        first.close()
        second.close()
