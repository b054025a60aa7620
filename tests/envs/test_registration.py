"""Gymnasium registration: every name registered, idempotent, and no MuJoCo import at `import sb3_ef`."""

import subprocess
import sys
import warnings

import gymnasium as gym

from sb3_ef.envs.registration import register_envs
from sb3_ef.envs.tasks import ENV_NAMES


def test_every_name_is_registered_once():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # gymnasium warns when an id is registered again
        register_envs()
        register_envs()
    for name in ENV_NAMES:
        assert gym.spec(f"{name}-v0").kwargs == {"name": name}
    assert gym.spec("toy/agent-v0").entry_point == "sb3_ef.envs.toy:ToyAgentEnv"


def test_toy_env_through_gym_make():
    env = gym.make("toy/agent-v0", size=16)
    assert env.reset(seed=0)[0].shape == (9, 16, 16)
    env.close()


def test_import_sb3_ef_does_not_import_mujoco():
    code = "import sys, sb3_ef; print(sorted({'mujoco', 'dm_control', 'metaworld'} & set(sys.modules)))"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def test_make_env_gives_the_spec_gym_make_would():
    from sb3_ef.envs import make_env

    env = make_env("dmc/cartpole-swingup", size=32, fast_render=True)
    assert env.spec.id == "dmc/cartpole-swingup-v0"
    assert env.spec.kwargs["size"] == 32 and env.spec.kwargs["fast_render"] is True
    again = gym.make(env.spec)  # the spec rebuilds the same env
    assert again.observation_space == env.observation_space
    again.close()
    env.close()
