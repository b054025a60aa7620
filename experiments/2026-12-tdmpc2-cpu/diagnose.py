r"""Reference levels and an update-count check for the TD-MPC2 CPU grid (tdmpc2_cpu.yml).

``levels``: returns of two policies that learn nothing, on the grid's env: uniform random actions and a zero
action.

``more-updates``: is a run short of updates? Load a grid checkpoint (model and replay buffer), evaluate it, run
``--updates`` more gradient steps on the same buffer without new experience, and evaluate again after them (or
every ``--eval-every`` updates), with the planner (the grid's evaluation action) and with the policy prior alone
(its mean action, no planning). ``--beta`` sets a TDMPC2-EF checkpoint's EF weight for those updates.

``planners``: does a bigger search help? Evaluate a checkpoint with the grid's planner, with TD-MPC2's reference
planner (6 iterations of 512 samples, 64 elites, 24 policy-prior trajectories) on the same weights, and with the
policy prior alone.

``gradients``: what moves the encoder of a TDMPC2-EF run? On ``--batches`` batches of a checkpoint's replay buffer,
the gradient norms of TD-MPC2's loss and of EF's (each over the parameters it is clipped on, and over the encoder
alone), before and after their clips to ``max_grad_norm`` (the update clips them apart and adds them).

    MUJOCO_GL=egl python experiments/2026-12-tdmpc2-cpu/diagnose.py levels --episodes 10
    MUJOCO_GL=egl python experiments/2026-12-tdmpc2-cpu/diagnose.py planners CHECKPOINT_DIR 4000 --episodes 3
    MUJOCO_GL=egl python experiments/2026-12-tdmpc2-cpu/diagnose.py more-updates CHECKPOINT_DIR 7000 \
        --updates 6000 --eval-every 2000
    python experiments/2026-12-tdmpc2-cpu/diagnose.py gradients CHECKPOINT_DIR 12000 --batches 20
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.logger import configure
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_ef import TDMPC2, TDMPC2EF, make_env
from sb3_ef.tdmpc2.planner import MPPIPlanner

ENV_KWARGS = {"size": 64, "frame_stack": 3, "action_repeat": 8, "fast_render": True, "episode_length": 1000}


def episode_returns(policy: Any, episodes: int, seed: int) -> list[float]:
    """Returns of ``policy`` (anything with SB3's ``predict``) on ``episodes`` episodes of the grid's env."""
    env = DummyVecEnv([lambda: Monitor(make_env("dmc/cartpole-balance", seed=seed, **ENV_KWARGS))])
    returns, _ = evaluate_policy(policy, env, n_eval_episodes=episodes, deterministic=True, return_episode_rewards=True)
    env.close()
    return [float(value) for value in returns]


class FixedPolicy:
    """Ignores its observations: uniform random actions (``"random"``) or zeros (``"zero"``)."""

    def __init__(self, action_space: gym.spaces.Box, kind: str, seed: int):
        self.action_space, self.kind = action_space, kind
        self.action_space.seed(seed)

    def predict(self, observation, state=None, episode_start=None, deterministic=False):
        if self.kind == "random":
            return np.stack([self.action_space.sample() for _ in range(len(observation))]), state
        return np.zeros((len(observation), *self.action_space.shape), np.float32), state


class PriorPolicy:
    """A TD-MPC2 model's policy prior: its mean action on the encoded observation, without planning."""

    def __init__(self, model: TDMPC2):
        self.model = model

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        with th.no_grad():
            latent = self.model.policy.encode(th.as_tensor(observation, device=self.model.device))
            return self.model.world_model.pi(latent).mean.cpu().numpy(), state


def summary(returns: list[float]) -> str:
    return f"{np.mean(returns):6.1f} +- {np.std(returns, ddof=1):5.1f} (n={len(returns)})"


def levels(args: argparse.Namespace) -> None:
    space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    for kind in ("random", "zero"):
        print(f"{kind:6s} {summary(episode_returns(FixedPolicy(space, kind, args.seed), args.episodes, args.seed))}")


def load_checkpoint(args: argparse.Namespace) -> TDMPC2:
    """The grid checkpoint ``args.checkpoints`` at ``args.step``, with its replay buffer and a silent logger."""
    th.set_num_threads(1)
    algorithm = TDMPC2EF if "tdmpc2_ef" in str(args.checkpoints) else TDMPC2
    model = algorithm.load(args.checkpoints / f"rl_model_{args.step}_steps.zip", device="cpu")
    model.load_replay_buffer(args.checkpoints / f"rl_model_replay_buffer_{args.step}_steps.pkl")
    model.set_logger(configure(None, format_strings=[]))  # a loaded model has none until learn()
    th.manual_seed(args.seed)
    return model


def evaluate(model: TDMPC2, label: str, args: argparse.Namespace, prior: bool = True) -> None:
    """Print the returns of the model's planner and (with ``prior``) of its policy prior alone."""
    policies = [("planner", model), ("prior", PriorPolicy(model))] if prior else [("planner", model)]
    for name, policy in policies:
        print(f"{label:32s} {name:8s} {summary(episode_returns(policy, args.episodes, args.seed))}", flush=True)


def planners(args: argparse.Namespace) -> None:
    model = load_checkpoint(args)
    evaluate(model, f"grid planner, step {args.step}", args)
    model.policy.planner = MPPIPlanner(horizon=model.horizon, gamma=model.gamma)
    evaluate(model, "reference planner 6 x 512", args, prior=False)


def more_updates(args: argparse.Namespace) -> None:
    model = load_checkpoint(args)
    if args.beta is not None:
        if not isinstance(model, TDMPC2EF):
            raise SystemExit(f"--beta needs a TDMPC2-EF checkpoint, got a {type(model).__name__} one")
        model.auxiliary.beta = args.beta
        print(f"EF's weight beta set to {args.beta}")
    evaluate(model, f"{type(model).__name__} at step {args.step}", args)
    done, every = 0, args.eval_every or args.updates
    while done < args.updates:
        updates = min(every, args.updates - done)
        start = time.perf_counter()
        model.train(gradient_steps=updates, batch_size=model.batch_size)
        done += updates
        print(f"{updates} updates on {model.replay_buffer.size()} transitions: {time.perf_counter() - start:.0f} s")
        evaluate(model, f"+ {done} updates, no new data", args)


def _norm(grads: tuple[th.Tensor | None, ...], params: list[th.Tensor], only: set[int] | None = None) -> float:
    """The total norm of ``grads`` (of ``params``), or of those whose parameter is in ``only`` (ids)."""
    kept = [
        grad
        for grad, param in zip(grads, params, strict=True)
        if grad is not None and (only is None or id(param) in only)
    ]
    return float(th.nn.utils.get_total_norm(kept))


def gradients(args: argparse.Namespace) -> None:
    model = load_checkpoint(args)
    if not isinstance(model, TDMPC2EF):
        raise SystemExit(f"gradients needs a TDMPC2-EF checkpoint, got a {type(model).__name__} one")
    host_params, ef_params = model._gradient_groups()
    encoder = {id(param) for param in model.world_model.encoder.parameters()}
    rows = []
    for _ in range(args.batches):
        losses, (auxiliary_loss, _), _, _ = model.losses(model.replay_buffer.sample(model.batch_size))
        host = model._host_loss(losses)
        host_grads = th.autograd.grad(host, host_params, retain_graph=True, allow_unused=True)
        ef_grads = th.autograd.grad(auxiliary_loss, ef_params, allow_unused=True)
        host_total, ef_total = _norm(host_grads, host_params), _norm(ef_grads, ef_params)
        host_encoder, ef_encoder = _norm(host_grads, host_params, encoder), _norm(ef_grads, ef_params, encoder)
        host_scale, ef_scale = min(1.0, model.max_grad_norm / host_total), min(1.0, model.max_grad_norm / ef_total)
        rows.append(
            [host_total, ef_total, host_encoder, ef_encoder, host_encoder * host_scale, ef_encoder * ef_scale]
            + [float(losses[key].detach()) for key in ("consistency_loss", "reward_loss", "value_loss", "ef_loss")]
        )
    names = ["grad norm: TD-MPC2, all", "grad norm: EF, all", "grad norm: TD-MPC2, encoder", "grad norm: EF, encoder"]
    names += ["grad norm: TD-MPC2, encoder, clipped", "grad norm: EF, encoder, clipped"]
    names += ["consistency loss", "reward loss", "value loss", "EF loss (unweighted)"]
    medians = np.median(np.array(rows), axis=0)
    print(f"step {args.step}, {args.batches} batches of {model.batch_size}, max_grad_norm {model.max_grad_norm}:")
    for name, value in zip(names, medians, strict=True):
        print(f"  {name:40s} {value:10.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    level_parser = commands.add_parser("levels", help="random and zero-action returns")
    planner_parser = commands.add_parser("planners", help="a checkpoint with the grid's and the reference planner")
    update_parser = commands.add_parser("more-updates", help="a checkpoint trained further on its own buffer")
    update_parser.add_argument("--updates", type=int, default=3000)
    update_parser.add_argument("--eval-every", type=int, default=None, help="updates between evaluations")
    update_parser.add_argument("--beta", type=float, default=None, help="TDMPC2-EF: EF's weight for these updates")
    gradient_parser = commands.add_parser("gradients", help="TD-MPC2's and EF's gradient norms on an EF checkpoint")
    gradient_parser.add_argument("--batches", type=int, default=20)
    for sub in (planner_parser, update_parser, gradient_parser):
        sub.add_argument("checkpoints", type=Path, help="a run's checkpoints folder")
        sub.add_argument("step", type=int, help="the checkpoint's step")
    for sub in (level_parser, planner_parser, update_parser, gradient_parser):
        sub.add_argument("--episodes", type=int, default=5)
        sub.add_argument("--seed", type=int, default=123)
    args = parser.parse_args()
    commands_by_name = {"levels": levels, "planners": planners, "more-updates": more_updates, "gradients": gradients}
    commands_by_name[args.command](args)


if __name__ == "__main__":
    main()
