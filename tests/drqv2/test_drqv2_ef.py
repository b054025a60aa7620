import math

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback, EvalCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_ef.common.buffers import SequenceReplayBuffer
from sb3_ef.drqv2 import DrQv2, DrQv2EF
from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.tdmpc2 import TDMPC2EF
from tests.helpers.drqv2 import EPISODE_STEPS, TINY_ALGO, TINY_POLICY, CueEnv, make_cue_env
from tests.helpers.sear import make_sear
from tests.helpers.tdmpc2 import TINY_EF_POLICY

PLAIN_POLICY = {key: TINY_POLICY[key] for key in ("net_arch", "trunk_dim")}
PLAIN_ALGO = {key: value for key, value in TINY_ALGO.items() if key not in ("ef_horizon", "babbling_steps")}


def make_model(env=None, **kwargs) -> DrQv2EF:
    params = {"policy_kwargs": TINY_POLICY, "seed": 0, **TINY_ALGO, **kwargs}
    return DrQv2EF("CnnPolicy", env if env is not None else make_cue_env(), **params)


def filled_batch(model: DrQv2EF, steps: int = 30):
    """Collect ``steps`` random transitions without updating, then sample one batch."""
    model.learning_starts = steps + 1
    model.learn(steps)
    return model.replay_buffer.sample(model.batch_size)


def networks(model: DrQv2EF) -> dict[str, th.nn.Module]:
    return {"encoder": model.policy.encoder, "critic": model.critic, "actor": model.actor, "ef": model.ef}


def reached_by(loss: th.Tensor, model: DrQv2EF) -> set[str]:
    """The networks whose parameters get a nonzero gradient from ``loss`` alone."""
    found = set()
    for name, module in networks(model).items():
        grads = th.autograd.grad(loss, list(module.parameters()), retain_graph=True, allow_unused=True)
        if any(grad is not None and bool(grad.abs().sum() > 0) for grad in grads):
            found.add(name)
    return found


def test_each_loss_reaches_only_its_networks():
    # Through the product's own update code: a detach, no_grad or frozen missing there shows here.
    model = make_model()
    batch = filled_batch(model)
    model.policy.set_training_mode(True)
    assert not any(param.requires_grad for param in model.critic_target.parameters())

    std = th.tensor(model.exploration_schedule(model.num_timesteps))
    observations, next_observations, targets = model._augment(batch)
    critic_loss, auxiliary_loss, _, _ = model._critic_and_auxiliary_loss(
        observations, next_observations, targets, batch, std
    )
    assert reached_by(critic_loss, model) == {"encoder", "critic"}
    assert reached_by(auxiliary_loss, model) == {"encoder", "ef"}

    # The update's two steps: the critic step sees the gradients of critic + EF; the actor's loss adds to the
    # actor's alone, so the encoder, critic and EF still hold the critic step's gradients at the actor step.
    at_step: dict[str, dict[str, list[th.Tensor | None]]] = {}

    def record(step: str):
        def hook(*_) -> None:
            at_step[step] = {
                name: [None if param.grad is None else param.grad.clone() for param in module.parameters()]
                for name, module in networks(model).items()
            }

        return hook

    model.critic.optimizer.register_step_pre_hook(record("critic"))
    model.actor.optimizer.register_step_pre_hook(record("actor"))
    model._update(batch)
    critic_step, actor_step = at_step["critic"], at_step["actor"]
    assert {name for name, grads in critic_step.items() if any(g is not None for g in grads)} == {
        "encoder", "critic", "ef"
    }  # fmt: skip
    assert any(grad is not None and grad.abs().sum() > 0 for grad in actor_step["actor"])
    for name in ("encoder", "critic", "ef"):
        unchanged = [th.equal(a, b) for a, b in zip(critic_step[name], actor_step[name], strict=True)]
        assert all(unchanged), f"the actor's loss reached the {name}"
    assert all(param.requires_grad for param in model.critic.parameters())


def test_ef_target_is_the_frame_k_steps_ahead_shifted_with_the_context():
    model = make_model()
    batch = filled_batch(model)
    observations, _, window = model._augment(batch)
    rows = th.arange(model.batch_size)
    assert window.steps.min() >= 1 and window.steps.max() <= model.ef_horizon
    assert th.equal(window.valid, batch.future_mask[rows, window.steps - 1])
    unshifted_target = batch.future_frames[rows, window.steps - 1]
    # The cue env's moving dot and lit half make shifts visible: one offset must explain both images of a sample.
    for sample in range(model.batch_size):
        assert any(
            th.equal(observations[sample, -3:], _shift(batch.observations[sample, -3:], dy, dx))
            and th.equal(window.target[sample], _shift(unshifted_target[sample], dy, dx))
            for dy in range(-4, 5)
            for dx in range(-4, 5)
        )


def _shift(image: th.Tensor, dy: int, dx: int) -> th.Tensor:
    """Replicate-pad shift of a (C, h, w) image by (dy, dx) pixels."""
    height, width = image.shape[-2:]
    rows = (th.arange(height) + dy).clamp(0, height - 1)
    cols = (th.arange(width) + dx).clamp(0, width - 1)
    return image[:, rows][:, :, cols]


def test_train_logs_the_losses():
    model = make_model()
    model.learn(40)
    logged = model.logger.name_to_value
    for key in ("critic_loss", "actor_loss", "ef_loss", "q_values", "exploration_std", "n_updates"):
        assert f"train/{key}" in logged
    assert model._n_updates == 40 - TINY_ALGO["learning_starts"]
    assert logged["train/exploration_std"] == pytest.approx(1.0 - 0.9 * 40 / 500_000, abs=1e-4)


def test_critic_target_follows_slowly():
    model = make_model(tau=0.01)
    before = [param.clone() for param in model.critic_target.parameters()]
    model.learn(TINY_ALGO["learning_starts"] + 3)
    moved = [
        (target - old).abs().max() / ((online - old).abs().max() + 1e-12)
        for old, target, online in zip(before, model.critic_target.parameters(), model.critic.parameters(), strict=True)
    ]
    assert max(moved) > 0 and max(moved) < 0.1


def test_seeded_runs_give_identical_losses():
    logs = []
    for _ in range(2):
        model = make_model(seed=7)
        model.learn(30)
        logs.append(dict(model.logger.name_to_value))
    assert logs[0] == logs[1]
    assert logs[0]["train/critic_loss"] > 0


def test_save_load_is_exact(tmp_path):
    model = make_model()
    model.learn(30)
    observations = np.stack([make_cue_env().observation_space.sample() for _ in range(3)])
    model.save(tmp_path / "model")
    loaded = DrQv2EF.load(tmp_path / "model", env=make_cue_env())
    assert np.array_equal(loaded.predict(observations, deterministic=True)[0], model.predict(observations)[0])
    for name in ("actor", "critic"):
        saved_state = getattr(model, name).optimizer.state_dict()["state"]
        loaded_state = getattr(loaded, name).optimizer.state_dict()["state"]
        assert saved_state.keys() == loaded_state.keys() and len(saved_state) > 0
        assert all(th.equal(saved_state[k]["exp_avg"], loaded_state[k]["exp_avg"]) for k in saved_state)
    for original, copy in zip(model.critic_target.parameters(), loaded.critic_target.parameters(), strict=True):
        assert th.equal(original, copy)
    assert loaded.ef is not None and loaded.exploration_schedule(0) == pytest.approx(1.0)
    loaded.learn(5, reset_num_timesteps=False)


def test_load_checks_the_horizon_of_the_saved_model(tmp_path):
    make_model().save(tmp_path / "model")  # ef_horizon 3
    assert DrQv2EF.load(tmp_path / "model", env=make_cue_env(episode_steps=5)).ef_horizon == 3
    with pytest.raises(ValueError, match="expected ef_horizon <= 2, got 3"):
        DrQv2EF.load(tmp_path / "model", env=make_cue_env(episode_steps=2))


def test_deterministic_predict_is_the_actor_mean():
    model = make_model()
    observation = make_cue_env().observation_space.sample()
    action, _ = model.predict(observation, deterministic=True)
    with th.no_grad():
        mean = model.actor(model.encode(th.as_tensor(observation[None])))
    # predict() maps [-1, 1] to the action bounds and back (identity here, up to float32 rounding).
    assert np.allclose(action, mean.numpy()[0], atol=1e-6)
    assert np.array_equal(action, model.predict(observation, deterministic=True)[0])


class ActionRecorder(BaseCallback):
    """Records the actions stored in the buffer at every rollout step."""

    def __init__(self):
        super().__init__()
        self.actions: list[np.ndarray] = []

    def _on_step(self) -> bool:
        self.actions.append(self.locals["buffer_actions"][0].copy())
        return True


def test_babbling_actions_are_signs_then_policy_actions():
    model = make_model(babbling_steps=25, learning_starts=20, buffer_size=200)
    recorder = ActionRecorder()
    model.learn(40, callback=recorder)
    actions = np.array(recorder.actions)
    assert actions.shape == (40, 2)
    assert np.array_equal(np.abs(actions[:25]), np.ones_like(actions[:25]))
    assert np.all(np.abs(actions[25:]) < 1.0)
    assert model.logger.name_to_value["rollout/babbling"] == 0.0  # babbling has ended


def test_two_envs():
    env = DummyVecEnv([make_cue_env, make_cue_env])
    model = make_model(env)
    model.learn(40)
    assert model.n_envs == 2 and model.num_timesteps == 40
    assert model.replay_buffer.n_envs == 2 and model._n_updates > 0


def test_eval_and_checkpoint_callbacks_and_progress_bar(tmp_path):
    model = make_model()
    eval_callback = EvalCallback(
        Monitor(make_cue_env()), eval_freq=20, n_eval_episodes=1, log_path=str(tmp_path), verbose=0
    )
    checkpoint = CheckpointCallback(save_freq=20, save_path=str(tmp_path), name_prefix="drqv2")
    model.learn(40, callback=[eval_callback, checkpoint], progress_bar=True)
    assert eval_callback.last_mean_reward != -np.inf
    assert (tmp_path / "evaluations.npz").exists() and (tmp_path / "drqv2_40_steps.zip").exists()
    DrQv2EF.load(tmp_path / "drqv2_40_steps.zip")


def test_plain_drqv2_has_no_ef_and_the_reference_encoder():
    model = DrQv2("CnnPolicy", make_cue_env(size=84), policy_kwargs=PLAIN_POLICY, seed=0, **PLAIN_ALGO)
    assert not hasattr(model, "ef") and not hasattr(model, "babbling_steps")
    assert model.policy.encoder.features_dim == 32 * 35 * 35
    assert isinstance(model.replay_buffer, SequenceReplayBuffer) and model.replay_buffer.n_steps == 3
    model.learn(20)
    assert "train/ef_loss" not in model.logger.name_to_value and model._n_updates > 0
    assert model.encode(th.zeros(1, 9, 84, 84, dtype=th.uint8)).shape == (1, 39200)


def test_ef_model_exposes_the_contract():
    model = make_model()
    assert model.frame_shape == (3, 32, 32)
    assert model.ef.agent_dim == TINY_POLICY["agent_dim"] and model.ef.horizon == TINY_ALGO["ef_horizon"]
    assert model.encode(th.zeros(2, 9, 32, 32, dtype=th.uint8)).shape == (2, TINY_POLICY["features_dim"])
    assert model.replay_buffer.horizon == TINY_ALGO["ef_horizon"]


def test_default_hyperparameters_follow_the_reference():
    model = DrQv2EF("CnnPolicy", make_cue_env(), buffer_size=100, policy_kwargs={"ef_kwargs": TINY_POLICY["ef_kwargs"]})
    assert (model.learning_rate, model.batch_size, model.tau, model.gamma) == (1e-4, 256, 0.01, 0.99)
    assert (model.n_steps, model.learning_starts, model.train_freq.frequency) == (3, 2000, 2)
    assert (model.beta, model.ef_horizon, model.babbling_steps, model.babbling_mode) == (1.0, 10, 12_500, "sign")
    assert model.policy.encoder.features_dim == 2048 and model.ef.agent_dim == 32
    assert model.exploration_schedule(500_000) == pytest.approx(0.1)


class DiscreteCueEnv(CueEnv):
    def __init__(self):
        super().__init__()
        self.action_space = spaces.Discrete(2)


class VectorEnv(gym.Env):
    observation_space = spaces.Box(-1.0, 1.0, (4,), np.float32)
    action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)


@pytest.mark.parametrize(
    ("env", "kwargs", "message"),
    [
        (VectorEnv(), {}, r"uint8 Box of shape \(3 \* frame_stack, height, width\), got Box\(-1.0, 1.0, \(4,\)"),
        (DiscreteCueEnv(), {}, r"continuous \(Box\) action space, got Discrete\(2\)"),
        (CueEnv(size=16), {}, r"16x16 are too small .*at least 21x21"),
        (make_cue_env(episode_steps=5), {"ef_horizon": 6}, r"expected ef_horizon <= 5, got 6"),
        (make_cue_env(), {"policy_kwargs": {**TINY_POLICY, "features_dim": 8}}, r"feature_dim=8\), got 8"),
        (make_cue_env(), {"replay_buffer_class": ReplayBuffer}, r"must be a SequenceReplayBuffer .*got ReplayBuffer"),
        (make_cue_env(), {"beta": 0.0}, r"beta must be a positive number \(use DrQv2 .*got 0.0"),
        (make_cue_env(), {"ef_horizon": 0}, r"ef_horizon must be a positive integer, got 0"),
    ],
)
def test_bad_input_is_rejected_at_construction(env, kwargs, message):
    with pytest.raises(ValueError, match=message):
        make_model(env, **kwargs)


def test_horizon_up_to_the_episode_length_is_accepted():
    model = make_model(make_cue_env(episode_steps=EPISODE_STEPS), ef_horizon=EPISODE_STEPS)
    assert model.ef.horizon == EPISODE_STEPS


def test_learns_to_read_the_cue():
    """The reward needs the image (the cue changes every step): an untrained actor earns about 0 per episode of 20,
    a trained one close to 20."""
    model = make_model(
        buffer_size=2000,
        batch_size=16,
        learning_starts=100,
        babbling_steps=100,
        n_steps=1,
        exploration_std=0.3,
        learning_rate=1e-3,
    )
    untrained, _ = evaluate_policy(model, make_cue_env(), n_eval_episodes=10, warn=False)
    model.learn(350)
    trained, _ = evaluate_policy(model, make_cue_env(), n_eval_episodes=10, warn=False)
    assert abs(untrained) < 5.0
    assert trained > 15.0


def make_tdmpc2_ef() -> TDMPC2EF:
    return TDMPC2EF(
        "CnnPolicy", ToyAgentEnv(size=64, max_episode_steps=20), learning_starts=10, batch_size=4, buffer_size=300,
        ef_horizon=5, babbling_steps=0, seed_burst=False, seed=0, policy_kwargs=TINY_EF_POLICY,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("make", "host"),
    [(make_model, "drqv2.drqv2"), (make_sear, "drqv2.drqv2"), (make_tdmpc2_ef, "tdmpc2.tdmpc2")],
    ids=["DrQv2EF", "SEAR", "TDMPC2EF"],
)
def test_aux_grad_ratio_is_logged_and_leaves_the_updates_unchanged(make, host, monkeypatch):
    def learned() -> tuple[dict[str, float], list[th.Tensor]]:
        model = make()
        model.learn(model.learning_starts + 4)
        return dict(model.logger.name_to_value), [param.detach().clone() for param in model.policy.parameters()]

    logged, parameters = learned()  # the first update computes the ratio
    ratio = logged.pop("train/aux_grad_ratio")
    assert math.isfinite(ratio) and ratio > 0
    monkeypatch.setattr(f"sb3_ef.{host}.aux_grad_ratio_due", lambda n_updates: False)
    unlogged, unchanged = learned()
    assert logged == unlogged  # the same losses, with or without the ratio
    assert all(th.equal(a, b) for a, b in zip(parameters, unchanged, strict=True))
