"""Where does EF act on a DrQ-v2 run? Gradient norms at the shared encoder, feature scale and actor saturation.

Loads a checkpoint (model zip and the replay buffer saved beside it, e.g. from ``sb3-ef benchmark``'s
``checkpoints/`` folder), draws one batch with a seeded sampler and prints, for that batch: the critic loss and its
gradient norm over the encoder's parameters, EF's loss (times beta) and its gradient norm over the same parameters
(DrQv2EF only), the mean feature norm, and the share of the actor's mean actions within 0.01 of the bounds.

    python benchmarks/ef_gradients.py CHECKPOINT.zip REPLAY_BUFFER.pkl [--algo drqv2_ef] [--batch-size 64]
"""

from __future__ import annotations

import argparse
import json
import pickle

import torch as th

from sb3_ef.zoo.registration import algorithm_classes


def encoder_grad_norm(loss: th.Tensor, parameters: list[th.nn.Parameter]) -> float:
    """L2 norm of ``loss``'s gradient over ``parameters`` (the graph is kept for the next loss)."""
    grads = th.autograd.grad(loss, parameters, retain_graph=True, allow_unused=True)
    return float(th.sqrt(sum((grad**2).sum() for grad in grads if grad is not None)))


def diagnose(algo: str, model_path: str, buffer_path: str, batch_size: int, seed: int) -> dict[str, float]:
    """The figures of the module docstring for one seeded batch of the checkpoint's buffer."""
    model = algorithm_classes()[algo].load(model_path, device="cpu", buffer_size=1000)
    with open(buffer_path, "rb") as file:
        model.replay_buffer = pickle.load(file)
    model.replay_buffer.device = "cpu"
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
        "critic_loss": float(critic_loss),
        "encoder_grad_norm_critic": encoder_grad_norm(critic_loss, encoder),
        "feature_norm_mean": float(features.norm(dim=1).mean()),
        "actions_saturated_share": float((actions.abs() > 0.99).float().mean()),
    }
    ef_loss = model._ef_loss(features, batch.future_actions, window)
    if ef_loss is not None:
        result["beta_ef_loss"] = float(model.beta * ef_loss)
        result["encoder_grad_norm_ef"] = encoder_grad_norm(model.beta * ef_loss, encoder)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model")
    parser.add_argument("buffer")
    parser.add_argument("--algo", default="drqv2_ef", choices=["drqv2_ef", "drqv2"])
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    th.set_num_threads(1)
    result = diagnose(args.algo, args.model, args.buffer, args.batch_size, args.seed)
    print(json.dumps({key: round(value, 4) for key, value in result.items()}))


if __name__ == "__main__":
    main()
