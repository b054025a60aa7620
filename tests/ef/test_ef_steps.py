import pytest
import torch as th

from sb3_ef.ef import draw_rollout_steps


def test_batch_sampling_draws_one_k_for_all_and_covers_the_horizon():
    mask = th.ones(16, 5, dtype=th.bool)
    seen = set()
    for _ in range(200):
        steps = draw_rollout_steps(mask, 5, "batch")
        assert steps.shape == (16,) and steps.dtype == th.long
        assert (steps == steps[0]).all()
        seen.add(int(steps[0]))
    assert seen == {1, 2, 3, 4, 5}


def test_sample_sampling_draws_per_sample_among_valid_steps_only():
    mask = th.ones(400, 6, dtype=th.bool)
    mask[:200, 2:] = False  # episodes ending after two steps
    steps = draw_rollout_steps(mask, 6, "sample")
    assert set(steps[:200].tolist()) == {1, 2}
    assert set(steps[200:].tolist()) == {1, 2, 3, 4, 5, 6}
    assert mask[th.arange(400), steps - 1].all()


def test_sample_without_valid_step_still_gets_a_step_in_range():
    mask = th.zeros(50, 4, dtype=th.bool)
    steps = draw_rollout_steps(mask, 4, "sample")
    assert steps.min() >= 1 and steps.max() <= 4


def test_only_the_first_horizon_steps_of_a_wider_mask_are_used():
    mask = th.ones(100, 8, dtype=th.bool)
    assert draw_rollout_steps(mask, 3, "sample").max() <= 3
    assert draw_rollout_steps(mask, 3, "batch").max() <= 3


@pytest.mark.parametrize("mode", ["batch", "sample"])
def test_generator_makes_draws_reproducible(mode):
    mask = th.rand(32, 10) > 0.3
    first = draw_rollout_steps(mask, 10, mode, th.Generator().manual_seed(3))
    second = draw_rollout_steps(mask, 10, mode, th.Generator().manual_seed(3))
    assert th.equal(first, second)


def test_bad_arguments_are_rejected():
    with pytest.raises(ValueError, match="step_sampling"):
        draw_rollout_steps(th.ones(2, 3, dtype=th.bool), 3, "episode")
    with pytest.raises(ValueError, match=r"\(batch, >= 5\)"):
        draw_rollout_steps(th.ones(2, 3, dtype=th.bool), 5)
