"""The host machinery and EF's arguments (sb3_ef.ef.host), exercised through DrQv2EF / TDMPC2EF and their plain
algorithms."""

import inspect

import pytest
import torch as th
from stable_baselines3.common.buffers import ReplayBuffer

from sb3_ef import TDMPC2, TDMPC2EF, DrQv2, DrQv2EF
from sb3_ef.ef.host import check_ef_arguments, check_horizon_fits_episodes
from sb3_ef.envs.toy import ToyAgentEnv

TINY_POLICY = {
    "net_arch": [16], "trunk_dim": 8, "features_dim": 16, "agent_dim": 4,
    "ef_kwargs": {"rollout_hidden_dims": (8,), "decoder_channels": 4},
}  # fmt: skip
LEARNING_STARTS = 16


def toy_env() -> ToyAgentEnv:
    return ToyAgentEnv(size=32, max_episode_steps=20)


def make_drqv2(algorithm=DrQv2EF, **kwargs):
    params = {"buffer_size": 200, "batch_size": 4, "learning_starts": LEARNING_STARTS, "seed": 0, **kwargs}
    if algorithm is DrQv2EF:
        params = {"policy_kwargs": TINY_POLICY, "ef_horizon": 3, "babbling_steps": 0, **params}
    else:
        params = {"policy_kwargs": {"net_arch": [8], "trunk_dim": 8}, **params}
    return algorithm("CnnPolicy", toy_env(), **params)


def test_horizon_check():
    check_horizon_fits_episodes(10, 10)
    check_horizon_fits_episodes(10, None)
    check_horizon_fits_episodes(None, 3)
    with pytest.raises(ValueError, match="expected ef_horizon <= 9, got 10"):
        check_horizon_fits_episodes(10, 9)


def test_argument_checks_name_expected_and_received():
    with pytest.raises(ValueError, match=r"use Plain to train without Ego-Foresight\), got -1"):
        check_ef_arguments(-1, 10, 0, "sign", plain_variant="Plain")
    with pytest.raises(ValueError, match=r"use Plain .*got None"):
        check_ef_arguments(None, 10, 0, "sign", plain_variant="Plain")
    with pytest.raises(ValueError, match="babbling_steps must be >= 0, got -5"):
        check_ef_arguments(1.0, 10, -5, "sign", plain_variant="Plain")
    with pytest.raises(ValueError, match=r"babbling_mode must be one of \('sign', 'clamped_uniform'\), got 'gauss'"):
        check_ef_arguments(1.0, 10, 0, "gauss", plain_variant="Plain")
    check_ef_arguments(1.0, 10, 0, "sign", plain_variant="Plain")


@pytest.mark.parametrize(("plain", "ef_class"), [(DrQv2, DrQv2EF), (TDMPC2, TDMPC2EF)])
def test_plain_algorithms_take_the_ef_signature_without_ef_arguments(plain, ef_class):
    plain_parameters = inspect.signature(plain.__init__).parameters
    ef_parameters = inspect.signature(ef_class.__init__).parameters
    assert set(ef_parameters) - set(plain_parameters) == {
        "beta", "ef_horizon", "babbling_steps", "babbling_mode", "babbling_in_eval"
    }  # fmt: skip
    assert list(plain_parameters) == [name for name in ef_parameters if name in plain_parameters]
    with pytest.raises(TypeError, match="unexpected keyword argument 'beta'"):
        plain("CnnPolicy", ToyAgentEnv(size=64), beta=1.0)


@pytest.mark.parametrize("algorithm", [DrQv2, DrQv2EF])
def test_a_buffer_without_windows_is_rejected_at_construction(algorithm):
    with pytest.raises(ValueError, match=r"replay_buffer_class must be a SequenceReplayBuffer .*got ReplayBuffer"):
        make_drqv2(algorithm, replay_buffer_class=ReplayBuffer)


def test_caller_dicts_are_left_unchanged():
    policy_kwargs, buffer_kwargs = dict(TINY_POLICY), {"n_steps": 2}
    model = make_drqv2(policy_kwargs=policy_kwargs, replay_buffer_kwargs=buffer_kwargs)
    assert policy_kwargs == TINY_POLICY and buffer_kwargs == {"n_steps": 2}
    assert model.replay_buffer.n_steps == 2 and model.replay_buffer.horizon == 3


def test_plain_and_ef_hosts_log_under_their_own_class_names(tmp_path):
    small = {"net_arch": [8], "trunk_dim": 8}
    variants = [
        (DrQv2, {"policy_kwargs": small}),
        (DrQv2EF, {"policy_kwargs": {**small, "features_dim": 16, "agent_dim": 4}, "ef_horizon": 2}),
    ]
    for algorithm, kwargs in variants:
        env = ToyAgentEnv(size=32, max_episode_steps=8)
        model = algorithm(
            "CnnPolicy", env, buffer_size=100, learning_starts=4, batch_size=4, tensorboard_log=str(tmp_path), **kwargs
        )
        model.learn(8)
    assert sorted(path.name for path in tmp_path.iterdir()) == ["DrQv2EF_1", "DrQv2_1"]


def _poison(module: th.nn.Module) -> None:
    with th.no_grad():
        next(module.parameters()).fill_(float("nan"))


def test_non_finite_losses_raise_only_when_checked():
    for check in (False, True):
        model = make_drqv2(check_finite_losses=check)
        _poison(model.critic.q_networks[0])
        if check:
            with pytest.raises(ValueError, match=r"critic_loss is nan at update 1"):
                model.learn(LEARNING_STARTS + 1)
        else:
            model.learn(LEARNING_STARTS + 1)


def test_non_finite_world_model_loss_is_named():
    model = TDMPC2EF(
        "CnnPolicy", ToyAgentEnv(size=64, max_episode_steps=20), learning_starts=5, batch_size=4, buffer_size=100,
        ef_horizon=3, babbling_steps=0, check_finite_losses=True, seed=0,
        policy_kwargs={"num_channels": 4, "mlp_dim": 16, "num_q": 2, "agent_dim": 16,
                       "planner_kwargs": {"iterations": 1, "num_samples": 8, "num_elites": 2, "num_pi_trajs": 1},
                       "ef_kwargs": {"rollout_hidden_dims": (8,), "decoder_channels": 4}},
    )  # fmt: skip
    _poison(model.world_model.reward_head)
    with pytest.raises(ValueError, match=r"reward_loss is nan at update 1"):
        model.learn(6)


def test_ef_window_draws_k_from_the_model_seed_and_shifts_with_the_global_generator():
    windows = []
    for global_seed in (1, 2):
        model = make_drqv2(seed=5, learning_starts=100)
        model.learn(30)
        batch = model.replay_buffer.sample(8)
        th.manual_seed(global_seed)
        windows.append(model._augment_observations(batch, pad=4))
    (first, window), (second, other) = windows
    assert th.equal(window.steps, other.steps) and not th.equal(first, second)
    rows = th.arange(8)
    assert th.equal(window.valid, batch.future_mask[rows, window.steps - 1])


def test_one_update_returns_tensors_without_reading_them(monkeypatch):
    tdmpc2 = TDMPC2EF(
        "CnnPolicy", ToyAgentEnv(size=64, max_episode_steps=20), learning_starts=100, batch_size=4, buffer_size=100,
        ef_horizon=3, babbling_steps=0, seed=0,
        policy_kwargs={"num_channels": 4, "mlp_dim": 16, "num_q": 2, "agent_dim": 16,
                       "planner_kwargs": {"iterations": 1, "num_samples": 8, "num_elites": 2, "num_pi_trajs": 1},
                       "ef_kwargs": {"rollout_hidden_dims": (8,), "decoder_channels": 4}},
    )  # fmt: skip
    for model in (make_drqv2(learning_starts=100), tdmpc2):
        model.learn(20)
        batch = model.replay_buffer.sample(4)
        model.policy.set_training_mode(True)
        with monkeypatch.context() as patch:  # the update can be traced (torch.compile): no host sync by .item()
            patch.setattr(th.Tensor, "item", lambda self: pytest.fail("_update called .item()"))
            logs = model._update(batch)
        assert "ef_loss" in logs and all(isinstance(v, th.Tensor) and v.dim() == 0 for v in logs.values())
