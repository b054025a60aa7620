import pytest
import torch as th

from sb3_ef.ef import EgoForesight

B, FEATURES, ACTIONS, AGENT, H = 4, 24, 2, 6, 5


def make_ef(size: int = 32, **kwargs) -> EgoForesight:
    options = {"agent_dim": AGENT, "horizon": H, "rollout_hidden_dims": (16, 16), "decoder_channels": 8}
    options.update(kwargs)
    return EgoForesight(FEATURES, ACTIONS, (3, size, size), **options)


def frames(size: int = 32, batch: int = B) -> th.Tensor:
    return th.randint(0, 256, (batch, 3, size, size), dtype=th.uint8)


def test_split_puts_the_agent_first():
    ef = make_ef()
    h = th.randn(B, FEATURES)
    h_scene, h_agent = ef.split(h)
    assert th.equal(h_agent, h[:, :AGENT]) and th.equal(h_scene, h[:, AGENT:])
    assert ef.scene_dim == FEATURES - AGENT


def test_shapes_of_rollout_decode_and_open_loop_prediction_beyond_the_horizon():
    ef = make_ef()
    h_scene, h_agent = ef.split(th.randn(B, FEATURES))
    assert ef.rollout(h_agent, th.randn(B, 3, ACTIONS)).shape == (B, 3, AGENT)
    assert ef.decode(h_scene, h_agent).shape == (B, 3, 32, 32)
    predicted = ef.predict(th.randn(B, FEATURES), th.randn(B, 2 * H, ACTIONS))
    assert predicted.shape == (B, 2 * H, 3, 32, 32)
    assert predicted.min() >= 0 and predicted.max() <= 1


@pytest.mark.parametrize("step_sampling", ["batch", "sample"])
def test_loss_is_the_summed_squared_error_at_each_samples_step(step_sampling):
    ef = make_ef(step_sampling=step_sampling).eval()  # eval: BatchNorm must not depend on the batch composition
    h, actions, target = th.randn(B, FEATURES), th.randn(B, H, ACTIONS), frames()
    steps = ef.draw_steps(th.ones(B, H, dtype=th.bool)) if step_sampling == "batch" else th.tensor([1, 3, 5, 2])
    predicted = ef.predict(h, actions)[th.arange(B), steps - 1]
    expected = (predicted - target.float() / 255).pow(2).sum(dim=(1, 2, 3)).mean()
    th.testing.assert_close(ef.loss(h, actions, steps, target), expected)


def test_uint8_and_unit_float_targets_give_the_same_loss():
    ef = make_ef().eval()
    h, actions, target, steps = th.randn(B, FEATURES), th.randn(B, H, ACTIONS), frames(), th.full((B,), 2)
    th.testing.assert_close(ef.loss(h, actions, steps, target), ef.loss(h, actions, steps, target.float() / 255))


def test_only_the_longest_drawn_rollout_is_computed(monkeypatch):
    ef = make_ef()
    calls = []
    step = ef.rollout_block.step
    monkeypatch.setattr(ef.rollout_block, "step", lambda *args: calls.append(1) or step(*args))
    ef.loss(th.randn(B, FEATURES), th.randn(B, H, ACTIONS), th.tensor([1, 2, 2, 3]), frames())
    assert len(calls) == 3


def test_invalid_samples_contribute_nothing():
    ef = make_ef().eval()
    h, actions, target, steps = th.randn(B, FEATURES), th.randn(B, H, ACTIONS), frames(), th.tensor([1, 2, 3, 4])
    valid = th.tensor([True, False, True, False])
    expected = ef.loss(h[valid], actions[valid], steps[valid], target[valid])
    th.testing.assert_close(ef.loss(h, actions, steps, target, valid), expected)
    th.testing.assert_close(ef.loss(h, actions, steps, target, valid.float()), expected)


def test_no_valid_sample_gives_a_differentiable_zero():
    ef = make_ef()
    h = th.randn(B, FEATURES, requires_grad=True)
    loss = ef.loss(h, th.randn(B, H, ACTIONS), th.full((B,), 2), frames(), th.zeros(B, dtype=th.bool))
    loss.backward()
    assert loss.item() == 0 and h.grad is not None and h.grad.abs().sum() == 0


def test_gradient_reaches_both_feature_parts_and_all_parameters():
    ef = make_ef(step_sampling="sample")
    h = th.randn(B, FEATURES, requires_grad=True)
    steps = ef.draw_steps(th.ones(B, H, dtype=th.bool))
    ef.loss(h, th.randn(B, H, ACTIONS), steps, frames()).backward()
    assert h.grad[:, :AGENT].abs().sum() > 0 and h.grad[:, AGENT:].abs().sum() > 0
    for name, parameter in ef.named_parameters():
        assert parameter.grad is not None and parameter.grad.abs().sum() > 0, name


@pytest.mark.parametrize("size", [64, 84])
def test_paper_frame_sizes(size):
    ef = make_ef(size)
    loss = ef.loss(th.randn(2, FEATURES), th.randn(2, H, ACTIONS), th.tensor([H, 1]), frames(size, 2))
    assert loss.ndim == 0 and loss > 0
    assert ef.predict(th.randn(2, FEATURES), th.randn(2, 1, ACTIONS)).shape == (2, 1, 3, size, size)


def test_skip_connections_feed_the_context_feature_map():
    ef = make_ef(skip_channels=4)
    h, skip = th.randn(B, FEATURES), th.randn(B, 4, 13, 13, requires_grad=True)
    ef.loss(h, th.randn(B, H, ACTIONS), th.full((B,), 3), frames(), skip=skip).backward()
    assert skip.grad.abs().sum() > 0
    assert ef.predict(h, th.randn(B, 7, ACTIONS), skip).shape == (B, 7, 3, 32, 32)
    with pytest.raises(ValueError, match="skip"):
        ef.predict(h, th.randn(B, 2, ACTIONS))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"agent_dim": FEATURES}, "agent_dim"),
        ({"agent_dim": 0}, "agent_dim"),
        ({"horizon": 0}, "horizon"),
        ({"step_sampling": "episode"}, "step_sampling"),
        ({"size": 48}, "Unsupported frame size 48"),
    ],
)
def test_bad_configuration_is_rejected_at_construction(kwargs, message):
    with pytest.raises(ValueError, match=message):
        make_ef(**kwargs)


def test_bad_loss_inputs_are_rejected():
    ef = make_ef()
    h, actions, target, steps = th.randn(B, FEATURES), th.randn(B, H, ACTIONS), frames(), th.full((B,), 2)
    with pytest.raises(ValueError, match=rf"\(batch, {FEATURES}\)"):
        ef.loss(th.randn(B, FEATURES + 1), actions, steps, target)
    with pytest.raises(ValueError, match=r"\(4, 3, 32, 32\)"):
        ef.loss(h, actions, steps, frames(64))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        ef.loss(h, actions, steps, target.float())
    with pytest.raises(ValueError, match=rf"\[1, {H}\]"):
        ef.loss(h, actions, th.full((B,), H + 1), target)
    with pytest.raises(ValueError, match=rf"\[1, {H}\]"):
        ef.loss(h, actions, th.zeros(B, dtype=th.long), target)
    with pytest.raises(ValueError, match="integer steps"):
        ef.loss(h, actions, steps.float(), target)
    with pytest.raises(ValueError, match="valid"):
        ef.loss(h, actions, steps, target, th.ones(B, 1, dtype=th.bool))


def test_decode_batch_size_decodes_only_the_first_samples():
    subset = make_ef(decode_batch_size=2).eval()
    full = make_ef().eval()
    full.load_state_dict(subset.state_dict())
    h = th.randn(B, FEATURES, requires_grad=True)
    actions, steps, target, valid = th.randn(B, H, ACTIONS), th.tensor([1, 3, 5, 2]), frames(), th.ones(B)
    loss = subset.loss(h, actions, steps, target, valid)
    expected = full.loss(h[:2], actions[:2], steps[:2], target[:2], valid[:2])
    assert th.allclose(loss, expected)
    loss.backward()
    assert h.grad[:2].abs().sum() > 0 and h.grad[2:].abs().sum() == 0
    with pytest.raises(ValueError, match=r"decode_batch_size must be None \(all\) or a positive integer, got 0"):
        make_ef(decode_batch_size=0)
