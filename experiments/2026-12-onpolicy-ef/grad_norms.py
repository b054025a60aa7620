"""EF's gradient on PPO-EF's shared encoder at ``beta = 1`` against PPO's clipped one, over the first rollouts.

    python experiments/2026-12-onpolicy-ef/grad_norms.py

Per minibatch: the norm of EF's gradient on the encoder and on the encoder with EF's modules, PPO's before SB3's
clip and PPO's on the encoder after it; medians of each rollout, with three training rollouts between two rows.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.env_util import make_atari_env
from stable_baselines3.common.vec_env import VecFrameStack

from sb3_ef import PPOEF, make_env
from sb3_ef.auxiliary.host import gradient_norm
from sb3_ef.common.buffers.rollout_windows import rollout_minibatches


def collect(model: PPOEF) -> None:
    model.collect_rollouts(model.env, model._init_callback(None), model.rollout_buffer, model.n_steps)


def norms(model: PPOEF, rows: int = 3) -> None:
    model._setup_learn(10**9)
    encoder = list(model.policy.features_extractor.parameters())
    print("ef_encoder ef_all ppo_before_clip ppo_encoder_clipped")
    for _ in range(rows):
        collect(model)
        windows, measured = model._rollout_windows(), []
        for indices, data in rollout_minibatches(model.rollout_buffer, model.batch_size):
            features, ef_loss, _ = model._ef_loss(windows(indices))
            loss, _ = model._ppo_loss(data, features, 0.1, None)
            model.policy.optimizer.zero_grad()
            ef_loss.backward(retain_graph=True)
            ef = [gradient_norm(encoder), gradient_norm([*encoder, *model.auxiliary.parameters()])]
            model.policy.optimizer.zero_grad()
            loss.backward()
            ppo = th.nn.utils.clip_grad_norm_(model.policy.parameters(), model.max_grad_norm)
            measured.append([float(value) for value in (*ef, ppo, gradient_norm(encoder))])
        print(np.round(np.median(measured, axis=0), 3))
        for _ in range(3):
            collect(model)
            model.train()


def main() -> None:
    import ale_py

    gym.register_envs(ale_py)
    th.set_num_threads(1)
    pong = VecFrameStack(make_atari_env("PongNoFrameskip-v4", n_envs=4, seed=0), 4)
    print("Pong")
    norms(PPOEF("CnnPolicy", pong, n_steps=64, batch_size=128, n_epochs=2, beta=1.0, seed=0))
    reacher = make_env("dmc/reacher-easy", fast_render=True)
    print("dmc/reacher-easy")
    norms(PPOEF("CnnPolicy", reacher, n_steps=128, batch_size=64, n_epochs=2, beta=1.0, seed=0))


if __name__ == "__main__":
    main()
