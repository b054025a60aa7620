"""Scripted body-schema episodes on real Meta-World: deterministic for a seed, and each scenario does what it says
(the hammer is held, the gripper starts on the door handle, the distractor walks regardless of the actions)."""

import numpy as np
import pytest
from scripted import SCENARIOS, ScriptedCollector

STEPS = 8


@pytest.fixture(scope="module")
def episodes():
    """Per scenario at 32x32: episode 0, episode 1, and episode 0 again from the same collector."""
    collected = {}
    for name in SCENARIOS:
        with ScriptedCollector(name, size=32) as collector:
            collected[name] = tuple(collector.episode(seed=3, index=index, steps=STEPS) for index in (0, 1, 0))
    return collected


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_collection_is_deterministic_for_a_seed(episodes, name):
    episode, other, again = episodes[name]
    assert episode.frames.shape == (STEPS + 1, 3, 32, 32) and episode.actions.shape == (STEPS, 4)
    np.testing.assert_array_equal(episode.frames, again.frames)
    np.testing.assert_array_equal(episode.actions, again.actions)
    np.testing.assert_array_equal(episode.object, again.object)
    for part, mask in episode.masks.items():
        np.testing.assert_array_equal(mask, again.masks[part])
    assert not np.array_equal(episode.actions, other.actions)
    assert not np.array_equal(episode.frames, other.frames)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["hammer-held", "hammer-distractor"])
def test_a_fresh_collector_records_the_same_episode(episodes, name):
    with ScriptedCollector(name, size=32) as collector:
        fresh = collector.episode(seed=3, index=0, steps=STEPS)
    np.testing.assert_array_equal(fresh.frames, episodes[name][0].frames)
    np.testing.assert_array_equal(fresh.masks["agent"], episodes[name][0].masks["agent"])


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_babbling_is_signs_with_the_gripper_closed(episodes, name):
    actions = episodes[name][0].actions
    assert set(np.unique(actions[:, :3])) <= {-1.0, 1.0}
    np.testing.assert_array_equal(actions[:, 3], 1.0)
    masks = episodes[name][0].masks
    assert set(masks) == {"agent", SCENARIOS[name].part[0]}
    assert all(mask.shape == (STEPS + 1, 32, 32) and mask.any() for mask in masks.values())


def test_the_held_hammer_moves_with_the_hand_and_the_table_one_does_not(episodes):
    held, table = episodes["hammer-held"][0], episodes["hammer-table"][0]
    assert held.attached.all()
    assert held.object[0, 2] > 0.06  # lifted off the table
    hand_path = np.linalg.norm(np.diff(held.hand, axis=0), axis=1).sum()
    assert hand_path > 0.04  # the hand moves about 8 mm per agent step
    offset = held.object - held.hand
    np.testing.assert_allclose(offset, np.broadcast_to(offset[0], offset.shape), atol=0.02)
    assert np.linalg.norm(table.object - table.object[0], axis=1).max() < 0.01


def test_the_door_episode_starts_with_the_gripper_on_the_handle(episodes):
    door = episodes["door-handle"][0]
    assert np.linalg.norm(door.hand[0] - door.object[0]) < 0.06


def test_the_distractor_walks_whatever_the_actions(episodes):
    episode = episodes["hammer-distractor"][0]
    steps = np.abs(np.diff(episode.object[:, :2], axis=0))
    step = SCENARIOS["hammer-distractor"].distractor_step
    # Every agent step moves it by one random step on each table axis (unless clipped to its box).
    assert (np.abs(steps - step) < step / 10).mean() > 0.8
    assert np.linalg.norm(np.diff(episode.hand, axis=0), axis=1).min() > 0.002  # while the hand babbles


def test_unknown_scenario_is_refused():
    with pytest.raises(ValueError, match="hammer-held"):
        ScriptedCollector("hammer-flying")
