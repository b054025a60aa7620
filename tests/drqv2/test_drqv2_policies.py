import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sb3_ef.common.env_checks import check_stacked_frames
from sb3_ef.drqv2.policies import DrQv2EFPolicy, DrQv2Encoder, DrQv2Policy


def image_space(size: int, channels: int = 9) -> spaces.Box:
    return spaces.Box(0, 255, (channels, size, size), np.uint8)


ACTIONS = spaces.Box(-1.0, 1.0, (2,), np.float32)
PLAIN = {"net_arch": [16], "trunk_dim": 8, "features_dim": 48}
TINY = {**PLAIN, "agent_dim": 8}
TINY_EF = {"rollout_hidden_dims": (8,), "decoder_channels": 4}


@pytest.mark.parametrize(
    ("size", "features_dim", "expected_dim"),
    [(84, None, 32 * 35 * 35), (84, 2048, 2048), (64, 2048, 2048), (32, 128, 128), (21, 16, 16), (15, None, 32)],
)
def test_encoder_output_size(size, features_dim, expected_dim):
    encoder = DrQv2Encoder(image_space(size), features_dim=features_dim)
    observations = th.randint(0, 256, (2, 9, size, size), dtype=th.uint8)
    assert encoder.features_dim == expected_dim
    assert encoder(observations).shape == (2, expected_dim)


def test_encoder_pools_to_the_reference_size_at_84():
    encoder = DrQv2Encoder(image_space(84), features_dim=2048)
    linear = encoder.projection[-1]
    assert linear.in_features == 32 * 8 * 8


@pytest.mark.parametrize(("size", "features_dim", "smallest"), [(20, 2048, 21), (14, None, 15)])
def test_encoder_rejects_too_small_images(size, features_dim, smallest):
    with pytest.raises(ValueError, match=f"{size}x{size} are too small.*at least {smallest}x{smallest}"):
        DrQv2Encoder(image_space(size), features_dim=features_dim)


@pytest.mark.parametrize(
    "space",
    [
        spaces.Box(0.0, 1.0, (9, 32, 32), np.float32),
        spaces.Box(0, 255, (8, 32, 32), np.uint8),
        spaces.Box(0, 255, (32, 32), np.uint8),
        spaces.Box(-1.0, 1.0, (5,), np.float32),
    ],
)
def test_non_image_spaces_are_rejected(space):
    with pytest.raises(ValueError, match=r"uint8 Box of shape \(3 \* frame_stack, height, width\), got"):
        check_stacked_frames(space, "DrQ-v2")


def test_encoder_centres_pixels():
    encoder = DrQv2Encoder(image_space(32), features_dim=8)
    grey = th.full((1, 9, 32, 32), 127.5)
    with th.no_grad():
        # obs / 255 - 0.5 maps mid-grey to 0: with zero biases the conv stack then outputs zeros.
        for layer in encoder.convnet:
            if isinstance(layer, th.nn.Conv2d):
                layer.bias.zero_()
        assert th.allclose(encoder.convnet(grey / 255.0 - 0.5), th.zeros(()))


def make_policy(size: int = 32, **kwargs) -> DrQv2EFPolicy:
    params = {**TINY, "ef_kwargs": TINY_EF, **kwargs}
    return DrQv2EFPolicy(image_space(size), ACTIONS, lambda _: 1e-3, **params)


def test_policy_networks_and_shapes():
    policy = make_policy()
    observations = th.randint(0, 256, (4, 9, 32, 32), dtype=th.uint8)
    features = policy.encoder(observations)
    actions = policy.actor(features)
    assert features.shape == (4, 48)
    assert actions.shape == (4, 2) and actions.abs().max() <= 1.0
    q_values = policy.critic(features, actions)
    assert len(q_values) == 2 and all(q.shape == (4, 1) for q in q_values)
    assert (policy.agent_dim, policy.ef_kwargs) == (8, TINY_EF)
    assert policy.frame_shape == (3, 32, 32)
    assert th.equal(policy(observations), actions)


def test_critic_target_starts_equal_and_has_no_gradients():
    policy = make_policy()
    for online, target in zip(policy.critic.parameters(), policy.critic_target.parameters(), strict=True):
        assert th.equal(online, target)
        assert not target.requires_grad


def test_optimisers_split_representation_and_actor():
    policy = make_policy()
    critic_params = {id(p) for group in policy.critic.optimizer.param_groups for p in group["params"]}
    actor_params = {id(p) for group in policy.actor.optimizer.param_groups for p in group["params"]}
    assert {id(p) for p in policy.encoder.parameters()} <= critic_params
    assert {id(p) for p in policy.critic.parameters()} <= critic_params
    assert actor_params == {id(p) for p in policy.actor.parameters()}


def test_plain_policy_has_the_reference_encoder_and_no_ef_sizes():
    policy = DrQv2Policy(image_space(84), ACTIONS, lambda _: 1e-3, net_arch=[16], trunk_dim=8)
    assert policy.encoder.features_dim == 32 * 35 * 35 and policy.auxiliary is None
    with pytest.raises(TypeError, match="agent_dim"):
        DrQv2Policy(image_space(32), ACTIONS, lambda _: 1e-3, agent_dim=8)


def test_policy_rebuilds_from_constructor_parameters():
    policy = make_policy()
    rebuilt = DrQv2EFPolicy(**policy._get_constructor_parameters())
    rebuilt.load_state_dict(policy.state_dict())
    assert (rebuilt.agent_dim, rebuilt.ef_kwargs) == (policy.agent_dim, policy.ef_kwargs)
    observations = th.randint(0, 256, (3, 9, 32, 32), dtype=th.uint8)
    assert th.equal(rebuilt(observations), policy(observations))


def test_speed_options_keep_the_maths():
    fast = make_policy()
    plain = make_policy(channels_last=False, optimizer_kwargs={})
    plain.load_state_dict(fast.state_dict())
    assert fast.critic.optimizer.defaults["fused"] and not plain.critic.optimizer.defaults["fused"]
    assert fast.encoder.convnet[0].weight.is_contiguous(memory_format=th.channels_last)
    observations = th.randint(0, 256, (4, 9, 32, 32), dtype=th.uint8)
    assert th.allclose(fast(observations), plain(observations), atol=1e-6)


def test_net_arch_dict_gives_actor_and_critic_their_own_sizes():
    """SB3's usual dict(pi=[...], qf=[...]) spelling."""
    policy = DrQv2Policy(image_space(32), ACTIONS, lambda _: 1e-4, **{**PLAIN, "net_arch": {"pi": [16], "qf": [24, 8]}})
    actor_sizes = [layer.out_features for layer in policy.actor.mu if isinstance(layer, th.nn.Linear)]
    critic_sizes = [layer.out_features for layer in policy.critic.q_networks[0] if isinstance(layer, th.nn.Linear)]
    assert actor_sizes == [16, 2] and critic_sizes == [24, 8, 1]
    rebuilt = DrQv2Policy(**policy._get_constructor_parameters())
    assert [p.shape for p in rebuilt.critic_target.parameters()] == [p.shape for p in policy.critic.parameters()]


@pytest.mark.parametrize(
    ("net_arch", "message"),
    [
        ("big", "net_arch must be a list of positive layer sizes .* got 'big'"),
        ([256, -1], r"got \[256, -1\]"),
        ({"pi": [16]}, "exactly the keys 'pi' and 'qf', got \\['pi'\\]"),
        ({"pi": [16], "qf": "big"}, "net_arch must be"),
    ],
)
def test_bad_net_arch_is_named(net_arch, message):
    with pytest.raises(ValueError, match=message):
        DrQv2Policy(image_space(32), ACTIONS, lambda _: 1e-4, **{**PLAIN, "net_arch": net_arch})


@pytest.mark.parametrize("features_dim", [-5, 0, 2.5, True])
def test_bad_features_dim_is_named(features_dim):
    with pytest.raises(ValueError, match=f"features_dim must be a positive integer .*got {features_dim!r}"):
        DrQv2Encoder(image_space(32), features_dim=features_dim)
