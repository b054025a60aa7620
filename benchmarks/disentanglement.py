"""Disentanglement measurement of Ego-Foresight trained alone (no RL).

``babbling``: does EF put the agent into h_a? Train encoder + EgoForesight on motor-babbling data and track, on
held-out babbling episodes:

- the open-loop prediction error on agent pixels (squared error per pixel in [0, 1] units, averaged over
  k = 1..H and over the pixels where the agent is in the newest context frame or in the target frame), against
  the baseline of copying the newest context frame, and the same error over all pixels;
- precision / recall / IoU of the thresholded h_a saliency map (mean + 1 std rule) against the simulator's agent
  mask, for the frame predicted k steps ahead (k cycling over 1..H across samples); also the precision (= recall)
  of the "matched size" rule (the top pixels, as many as the true mask has); the agent's pixel fraction is the
  precision a random mask would get.

The train step is the hosts' (docs/architecture.md): SequenceReplayBuffer windows, one k per batch,
random_shift of context and target together, DrQ-v2 encoder with DrQv2-EF's projection, EgoForesight.loss.

    MUJOCO_GL=egl python benchmarks/disentanglement.py babbling --tasks dmc/reacher-easy metaworld/hammer

The body-schema measurements (held tool, door, distractor) are a study of their own:
``experiments/2026-12-body-schema/measure.py``.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass

import numpy as np
import torch as th

from sb3_ef.analysis.masks import mask_scores, threshold_saliency
from sb3_ef.analysis.saliency import compute_saliency
from sb3_ef.common.augmentation import random_shift
from sb3_ef.common.buffers import SequenceReplayBuffer
from sb3_ef.drqv2.policies import DrQv2Encoder
from sb3_ef.ef import EgoForesight
from sb3_ef.envs import make_env


@dataclass
class HeldOut:
    """Held-out babbling episodes as analysis windows: context observation, H actions, H target frames and
    agent masks of the newest context frame and of the H targets."""

    observations: np.ndarray  # (N, 3 * C, s, s) uint8
    actions: np.ndarray  # (N, H, A)
    targets: np.ndarray  # (N, H, 3, s, s) uint8
    masks: np.ndarray  # (N, H + 1, s, s) bool, index 0 = newest context frame


def babble(env, steps: int, rng: np.random.Generator, with_masks: bool):
    """Sign babbling (each action component -1 or +1): lists of (obs, next_obs, action, done, info, mask)."""
    observation, _ = env.reset(seed=int(rng.integers(2**31)))
    mask = env.unwrapped.agent_mask() if with_masks else None
    transitions = []
    for _ in range(steps):
        action = rng.choice([-1.0, 1.0], size=env.action_space.shape).astype(np.float32)
        next_observation, reward, terminated, truncated, info = env.step(action)
        next_mask = env.unwrapped.agent_mask() if with_masks else None
        transitions.append(
            (observation, next_observation, action, reward, terminated, truncated, info, mask, next_mask)
        )
        observation, mask = next_observation, next_mask
        if terminated or truncated:
            observation, _ = env.reset(seed=int(rng.integers(2**31)))
            mask = env.unwrapped.agent_mask() if with_masks else None
    return transitions


def held_out_windows(transitions, horizon: int, count: int, rng: np.random.Generator) -> HeldOut:
    """Windows of ``horizon`` steps that stay inside one episode, ``count`` of them at random starts."""
    starts = [
        index
        for index in range(len(transitions) - horizon + 1)
        if not any(t[4] or t[5] for t in transitions[index : index + horizon - 1])
    ]
    chosen = rng.choice(starts, size=min(count, len(starts)), replace=False)
    observations, actions, targets, masks = [], [], [], []
    for start in chosen:
        window = transitions[start : start + horizon]
        observations.append(window[0][0])
        actions.append(np.stack([t[2] for t in window]))
        targets.append(np.stack([t[1][-3:] for t in window]))
        masks.append(np.stack([window[0][7]] + [t[8] for t in window]))
    return HeldOut(*(np.stack(array) for array in (observations, actions, targets, masks)))


def evaluate(encoder, ef: EgoForesight, held_out: HeldOut, saliency_samples: int) -> dict[str, float]:
    """Agent-pixel prediction error of EF and of copying the newest context frame, and saliency mask scores."""
    encoder.eval(), ef.eval()
    with th.no_grad():
        h = encoder(th.as_tensor(held_out.observations))
        predicted = ef.predict(h, th.as_tensor(held_out.actions)).numpy()  # (N, H, 3, s, s) in [0, 1]
    encoder.train(), ef.train()
    targets = held_out.targets / 255.0
    copy = np.broadcast_to((held_out.observations[:, None, -3:] / 255.0), targets.shape)
    agent_pixels = (held_out.masks[:, 1:] | held_out.masks[:, :1])[:, :, None]  # (N, H, 1, s, s)
    weight = np.broadcast_to(agent_pixels, targets.shape)
    ef_squared, copy_squared = (predicted - targets) ** 2, (copy - targets) ** 2
    horizon = held_out.actions.shape[1]
    scores, matched_precisions = [], []
    for index in range(min(saliency_samples, len(held_out.observations))):
        k = 1 + index % horizon
        saliency = compute_saliency(held_out.observations[index], held_out.actions[index, :k], encoder=encoder, ef=ef)
        target = held_out.masks[index, k]
        scores.append(mask_scores(threshold_saliency(saliency.agent), target))
        if target.any():
            matched = threshold_saliency(saliency.agent, rule="top_fraction", fraction=target.mean())
            matched_precisions.append(mask_scores(matched, target).precision)
    return {
        "agent_mse_ef": float(ef_squared[weight].mean()),
        "agent_mse_copy": float(copy_squared[weight].mean()),
        "all_mse_ef": float(ef_squared.mean()),
        "all_mse_copy": float(copy_squared.mean()),
        "precision": float(np.nanmean([score.precision for score in scores])),
        "recall": float(np.nanmean([score.recall for score in scores])),
        "iou": float(np.nanmean([score.iou for score in scores])),
        "matched_precision": float(np.nanmean(matched_precisions)),
        "agent_fraction": float(held_out.masks[:, 1:].mean()),
    }


def run_task(task: str, args: argparse.Namespace) -> dict:
    rng = np.random.default_rng(args.seed)
    th.manual_seed(args.seed)
    env = make_env(task, size=args.size, fast_render=True, episode_length=args.episode_length, seed=args.seed)
    start = time.perf_counter()
    train = babble(env, args.train_steps, rng, with_masks=False)
    held_out = held_out_windows(babble(env, args.eval_steps, rng, with_masks=True), args.horizon, args.windows, rng)
    env.close()
    collect_seconds = time.perf_counter() - start

    buffer = SequenceReplayBuffer(
        args.train_steps + 100, env.observation_space, env.action_space, device="cpu", horizon=args.horizon
    )
    for observation, next_observation, action, reward, terminated, truncated, info, _, _ in train:
        info = {**info, "TimeLimit.truncated": truncated}
        buffer.add(observation[None], next_observation[None], action[None], np.array([reward]),
                   np.array([terminated or truncated]), [info])  # fmt: skip
    encoder = DrQv2Encoder(env.observation_space, features_dim=args.features_dim)
    ef = EgoForesight(args.features_dim, env.action_space.shape[0], frame_shape=(3, args.size, args.size),
                      agent_dim=args.agent_dim, horizon=args.horizon, rollout_hidden_dims=(256, 256),
                      decoder_channels=args.decoder_channels)  # fmt: skip
    optimizer = th.optim.Adam([*encoder.parameters(), *ef.parameters()], lr=args.lr)

    history = [{"update": 0, **evaluate(encoder, ef, held_out, args.saliency_samples)}]
    print(task, history[-1], flush=True)
    start = time.perf_counter()
    for update in range(1, args.updates + 1):
        batch = buffer.sample(args.batch_size)
        steps = ef.draw_steps(batch.future_mask)
        rows = th.arange(args.batch_size)
        target, valid = batch.future_frames[rows, steps - 1], batch.future_mask[rows, steps - 1]
        observations, target = random_shift(batch.observations, target, pad=4)
        loss = ef.loss(encoder(observations), batch.future_actions, steps, target, valid)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        if update % args.eval_every == 0 or update == args.updates:
            history.append(
                {"update": update, "loss": loss.item(), **evaluate(encoder, ef, held_out, args.saliency_samples)}
            )
            print(task, history[-1], flush=True)
    return {"task": task, "collect_seconds": collect_seconds, "train_seconds": time.perf_counter() - start,
            "history": history}  # fmt: skip


def add_babbling_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--tasks", nargs="+", default=["dmc/reacher-easy", "metaworld/hammer"])
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--episode-length", type=int, default=200, help="simulator steps per episode")
    parser.add_argument("--train-steps", type=int, default=3000, help="babbling agent steps for training")
    parser.add_argument("--eval-steps", type=int, default=400, help="babbling agent steps held out")
    parser.add_argument("--windows", type=int, default=64, help="held-out windows for the prediction error")
    parser.add_argument("--saliency-samples", type=int, default=16)
    parser.add_argument("--updates", type=int, default=1500)
    parser.add_argument("--eval-every", type=int, default=250)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--horizon", type=int, default=10)
    parser.add_argument("--features-dim", type=int, default=256)
    parser.add_argument("--agent-dim", type=int, default=32)
    parser.add_argument("--decoder-channels", type=int, default=32)
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", default="benchmarks/disentanglement.json")


def babbling(args: argparse.Namespace) -> None:
    th.set_num_threads(args.threads)
    results = {"args": vars(args), "tasks": [run_task(task, args) for task in args.tasks]}
    with open(args.out, "w") as file:
        json.dump(results, file, indent=2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    add_babbling_arguments(commands.add_parser("babbling", help="agent masks on babbling data"))
    babbling(parser.parse_args())


if __name__ == "__main__":
    main()
