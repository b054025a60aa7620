"""EpisodeActor acts as an evaluation does: each predict takes the state the previous one returned."""

from __future__ import annotations

import numpy as np

from sb3_ef import TDMPC2
from sb3_ef.common.acting import EpisodeActor
from sb3_ef.envs.toy import ToyAgentEnv
from tests.helpers.tdmpc2 import TINY_POLICY


def test_the_warm_start_plan_is_carried_within_an_episode_and_dropped_at_the_next():
    env = ToyAgentEnv(size=64)
    model = TDMPC2("CnnPolicy", env, buffer_size=100, policy_kwargs=TINY_POLICY, seed=0, device="cpu")
    observations = [env.reset(seed=0)[0]]
    for _ in range(3):
        observations.append(env.step(env.action_space.sample())[0])
    state, expected = None, []
    for index, observation in enumerate(observations):  # the loop SB3's evaluate_policy runs
        action, state = model.predict(observation, state, np.array([index == 0]), deterministic=True)
        expected.append(action)
    stateless = [model.predict(observation, deterministic=True)[0] for observation in observations]
    assert not np.allclose(expected[1:], stateless[1:])  # the carried plan changes the actions
    actor = EpisodeActor(model)
    for _ in range(2):  # a second episode starts from no plan again
        actor.reset()
        np.testing.assert_array_equal([actor(observation) for observation in observations], expected)
