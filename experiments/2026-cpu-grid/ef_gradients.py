"""Where does EF act on a DrQ-v2 run? Gradient norms at the shared encoder, feature scale and actor saturation.

Loads a checkpoint (model zip and the replay buffer saved beside it, e.g. from ``sb3-ef benchmark``'s
``checkpoints/`` folder), draws one batch with a seeded sampler and prints, for that batch: the critic loss and its
gradient norm over the encoder's parameters, EF's loss (times beta) and its gradient norm over the same parameters
(DrQv2EF only), the mean feature norm, the share of the actor's mean actions within 0.01 of the bounds, and how much
the policy and the critic depend on the state:

- ``feature_spread``: per feature, the standard deviation over the batch, averaged, divided by the features' RMS
  (0 when every observation maps to the same features);
- ``action_std``: the actor's mean action, standard deviation over the batch (averaged over action dimensions);
- ``action_majority``: the share of the batch whose mean action has the batch's most common sign, per dimension,
  averaged (1.0: the same push whatever the state, as a stalled cartpole policy does);
- ``critic_majority``: the same share for the sign the critic prefers, min-Q(s, +1) against min-Q(s, -1).

    python ef_gradients.py CHECKPOINT.zip REPLAY_BUFFER.pkl [--algo drqv2_ef] [--batch-size 64]
    python ef_gradients.py --checkpoints DIR [--algo drqv2]     # every rl_model_<N>_steps pair in DIR
"""

from __future__ import annotations

import argparse
import json
import pickle
import re
from pathlib import Path

import torch as th

from sb3_ef.zoo.registration import algorithm_classes


def encoder_grad_norm(loss: th.Tensor, parameters: list[th.nn.Parameter]) -> float:
    """L2 norm of ``loss``'s gradient over ``parameters`` (the graph is kept for the next loss)."""
    grads = th.autograd.grad(loss, parameters, retain_graph=True, allow_unused=True)
    return float(th.sqrt(sum((grad**2).sum() for grad in grads if grad is not None)))


def majority_share(values: th.Tensor) -> float:
    """Per column, the share of rows with the column's most common sign; averaged over columns."""
    positive = (values > 0).float().mean(dim=0)
    return float(th.maximum(positive, 1 - positive).mean())


def state_dependence(model, features: th.Tensor, actions: th.Tensor) -> dict[str, float]:
    """``feature_spread``, ``action_std``, ``action_majority`` and ``critic_majority`` (module docstring)."""
    rms = features.pow(2).mean().sqrt()
    with th.no_grad():
        push = {sign: th.full_like(actions, sign) for sign in (1.0, -1.0)}
        q = {sign: th.cat(model.critic(features, push[sign]), dim=1).min(dim=1).values for sign in push}
    return {
        "feature_spread": float(features.std(dim=0).mean() / rms),
        "action_std": float(actions.std(dim=0).mean()),
        "action_majority": majority_share(actions),
        "critic_majority": majority_share((q[1.0] - q[-1.0]).unsqueeze(1)),
    }


def diagnose(algo: str, model_path: str, buffer_path: str, batch_size: int, seed: int) -> dict[str, float]:
    """The figures of the module docstring for one seeded batch of the checkpoint's buffer."""
    model = algorithm_classes()[algo].load(model_path, device="cpu", buffer_size=1000)
    with open(buffer_path, "rb") as file:
        model.replay_buffer = pickle.load(file)
    model.replay_buffer.device = "cpu"
    return diagnose_model(model, batch_size, seed)


def diagnose_model(model, batch_size: int, seed: int) -> dict[str, float]:
    """The figures of the module docstring for one batch of ``model``'s replay buffer, its sampler seeded.

    The policy is put in training mode first, as an update does: EF's decoder has BatchNorm, whose batch statistics
    (training) and running ones (evaluation, a loaded model's mode) give different losses and gradients.
    """
    model.policy.set_training_mode(True)
    model.replay_buffer.seed(seed)
    batch = model.replay_buffer.sample(batch_size)
    std = model.exploration_schedule(model.num_timesteps)
    observations, next_observations, window = model._augment(batch)
    features = model.policy.encoder(observations)
    with th.no_grad():
        next_features = model.policy.encoder(next_observations)
        actions = model.actor(features)
    critic_loss, _ = model._critic_loss(features, batch, next_features, std)
    encoder = list(model.policy.encoder.parameters())
    result = {
        "step": model.num_timesteps,
        "critic_loss": float(critic_loss.detach()),
        "encoder_grad_norm_critic": encoder_grad_norm(critic_loss, encoder),
        "feature_norm_mean": float(features.detach().norm(dim=1).mean()),
        "actions_saturated_share": float((actions.abs() > 0.99).float().mean()),
        **state_dependence(model, features.detach(), actions),
    }
    if model.auxiliary is not None:
        beta_ef_loss, _ = model.auxiliary(features, window)
        result["beta_ef_loss"] = float(beta_ef_loss.detach())
        result["encoder_grad_norm_ef"] = encoder_grad_norm(beta_ef_loss, encoder)
    return result


def checkpoint_pairs(folder: str) -> list[tuple[str, str]]:
    """``(model, replay buffer)`` paths of every checkpoint in ``folder`` that has both, by step."""
    pairs = []
    for model_path in Path(folder).glob("*_steps.zip"):
        match = re.fullmatch(r"(.*)_(\d+)_steps\.zip", model_path.name)
        buffer_path = model_path.with_name(f"{match[1]}_replay_buffer_{match[2]}_steps.pkl") if match else None
        if buffer_path is not None and buffer_path.is_file():
            pairs.append((int(match[2]), str(model_path), str(buffer_path)))
    if not pairs:
        raise FileNotFoundError(f"No rl_model_<N>_steps.zip with its replay buffer .pkl in {folder}")
    return [(model_path, buffer_path) for _, model_path, buffer_path in sorted(pairs)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", nargs="?", help="checkpoint model .zip")
    parser.add_argument("buffer", nargs="?", help="its replay buffer .pkl")
    parser.add_argument(
        "--checkpoints", help="a folder of rl_model_<N>_steps.zip + rl_model_replay_buffer_<N>_steps.pkl"
    )
    parser.add_argument("--algo", default="drqv2_ef", choices=["drqv2_ef", "drqv2"])
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if (args.checkpoints is None) == (args.model is None or args.buffer is None):
        parser.error("give either MODEL and BUFFER, or --checkpoints DIR")
    th.set_num_threads(1)
    for model_path, buffer_path in (
        checkpoint_pairs(args.checkpoints) if args.checkpoints else [(args.model, args.buffer)]
    ):
        result = diagnose(args.algo, model_path, buffer_path, args.batch_size, args.seed)
        print(json.dumps({key: round(value, 4) for key, value in result.items()}), flush=True)


if __name__ == "__main__":
    main()
