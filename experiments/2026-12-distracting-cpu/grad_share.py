"""How hard pixel EF and latent EF pull on DrQv2EF's encoder next to the critic: ``aux_grad_ratio`` measured.

For each EF target, a DrQv2EF at the zoo's DMC defaults (``zoo_configs/drqv2_ef.yml``: batch 256, features 2048,
agent features 32, beta 1, horizon 10; 84x84 frames, 3 stacked, action repeat 2) fills its buffer with ``--fill``
agent steps, then the encoder-gradient norms of the critic loss and of the weighted EF loss are read on
``--batches`` replay batches (:func:`sb3_ef.auxiliary.host.encoder_gradient_ratio`), at initialisation and
again after each of ``--updates`` (cumulative counts of DrQ-v2 updates). Both models see the same environment steps
and the same batches (one seed). One line per (target, updates): the mean and range over the batches.

    MUJOCO_GL=egl nice -n 19 python experiments/2026-12-distracting-cpu/grad_share.py --updates 0 300
    # the study's own sizes (64x64, batch 64, features 512, agent features 16):
    MUJOCO_GL=egl nice -n 19 python experiments/2026-12-distracting-cpu/grad_share.py --size 64 --batch-size 64 \\
        --features-dim 512 --agent-dim 16
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch as th

from sb3_ef import DrQv2EF, make_env
from sb3_ef.auxiliary.host import encoder_gradient_ratio


def gradient_share(model: DrQv2EF, batches: int, seed: int) -> tuple[list[float], list[float], list[float]]:
    """The ratio, the critic's and the weighted EF loss's encoder-gradient norms on ``batches`` replay batches
    (drawn after seeding torch and numpy with ``seed``: the same batches for models with the same buffer)."""
    th.manual_seed(seed)
    np.random.seed(seed)
    encoder = [parameter for parameter in model.policy.encoder.parameters() if parameter.requires_grad]
    std = model.exploration_schedule(model.num_timesteps)
    ratios, critic_norms, ef_norms = [], [], []
    for _ in range(batches):
        batch = model.replay_buffer.sample(model.batch_size)
        observations, next_observations, targets = model._augment(batch)
        features = model.policy.encoder(observations)
        with th.no_grad():
            next_features = model.policy.encoder(next_observations)
        critic_loss, _ = model._critic_loss(features, batch, next_features, std)
        ef_loss, _ = model.auxiliary(features, targets)
        ratio = encoder_gradient_ratio(ef_loss, critic_loss, encoder)
        critic_grads = th.autograd.grad(critic_loss, encoder)
        critic_norm = th.sqrt(sum(grad.pow(2).sum() for grad in critic_grads))
        ratios.append(float(ratio))
        critic_norms.append(float(critic_norm))
        ef_norms.append(float(ratio * critic_norm))
    return ratios, critic_norms, ef_norms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="dmc/cartpole-balance-v0")
    parser.add_argument("--targets", nargs="+", default=["pixel", "latent"])
    parser.add_argument("--size", type=int, default=84)
    parser.add_argument("--batch-size", type=int, default=256)
    parser.add_argument("--features-dim", type=int, default=2048)
    parser.add_argument("--agent-dim", type=int, default=32)
    parser.add_argument("--beta", type=float, default=1.0)
    parser.add_argument("--loss-scale", type=float, default=None, help="latent EF's loss_scale (its default if unset)")
    parser.add_argument("--fill", type=int, default=1000, help="agent steps collected before the first update")
    parser.add_argument("--updates", type=int, nargs="+", default=[0], help="measure after this many updates")
    parser.add_argument("--batches", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    th.set_num_threads(1)
    print("target\tupdates\taux_grad_ratio mean [min, max]\tcritic norm\tEF norm\tseconds per update")
    for target in args.targets:
        ef_kwargs = {"target": target}
        if target == "latent" and args.loss_scale is not None:
            ef_kwargs["loss_scale"] = args.loss_scale
        env = make_env(args.task, seed=args.seed, size=args.size, frame_stack=3, action_repeat=2, fast_render=True)
        model = DrQv2EF(
            "CnnPolicy", env, buffer_size=args.fill + 2 * max(args.updates) + 1000, batch_size=args.batch_size,
            learning_starts=args.fill, beta=args.beta, seed=args.seed,
            policy_kwargs={"features_dim": args.features_dim, "agent_dim": args.agent_dim, "ef_kwargs": ef_kwargs},
        )  # fmt: skip
        model.learn(args.fill + 1)
        done = 0
        for updates in sorted(args.updates):
            start = time.perf_counter()
            if updates > done:  # train_freq 2, one update each: two agent steps per update
                model.learn(2 * (updates - done), reset_num_timesteps=False)
            per_update = (time.perf_counter() - start) / max(updates - done, 1)
            done = max(done, updates)
            ratios, critic, ef = gradient_share(model, args.batches, args.seed)
            print(
                f"{target}\t{done}\t{np.mean(ratios):.3f} [{min(ratios):.3f}, {max(ratios):.3f}]\t"
                f"{np.mean(critic):.3f}\t{np.mean(ef):.3f}\t{per_update:.2f}",
                flush=True,
            )
        env.close()
        del model


if __name__ == "__main__":
    main()
