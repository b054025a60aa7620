"""Every host's losses and parameters after a short seeded run: run before and after a refactor, then compare.

    python experiments/2026-12-host-redesign/fingerprint.py OUT.pt            # write
    python experiments/2026-12-host-redesign/fingerprint.py OUT.pt --against BEFORE.pt   # compare, bit for bit
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch as th
from stable_baselines3.common.logger import configure

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
import sb3_ef
from sb3_ef.envs.toy import ToyAgentEnv
from tests.helpers.drqv2 import TINY_ALGO, TINY_POLICY, make_cue_env
from tests.helpers.tdmpc2 import TINY_EF_POLICY
from tests.helpers.tdmpc2 import TINY_POLICY as TDMPC2_TINY

STEPS = 60
PLAIN_POLICY = {key: value for key, value in TINY_POLICY.items() if key not in ("agent_dim", "ef_kwargs")}
SB3_COMMON = {"buffer_size": 500, "batch_size": 8, "learning_starts": 16, "train_freq": 1}
SB3_POLICY = {"net_arch": [32, 32], "features_extractor_kwargs": {"features_dim": 64}}
SB3_EF_KWARGS = {"rollout_hidden_dims": (16,), "decoder_channels": 8}
EF_ARGS = {"ef_horizon": 3, "babbling_steps": 8, "beta": 0.7}


def cases() -> dict[str, tuple[type, dict, object]]:
    drqv2 = {**TINY_ALGO}
    latent = {**TINY_POLICY, "ef_kwargs": {"target": "latent", "rollout_hidden_dims": (16,), "projection_dim": 16}}
    toy = lambda: ToyAgentEnv(size=32, agent_masks=True)  # noqa: E731
    return {
        "DrQv2": (sb3_ef.DrQv2, dict({k: v for k, v in drqv2.items() if k not in ("ef_horizon", "babbling_steps")},
                                     policy_kwargs=PLAIN_POLICY), make_cue_env),
        "DrQv2EF": (sb3_ef.DrQv2EF, dict(drqv2, policy_kwargs=TINY_POLICY, **{**EF_ARGS, "babbling_steps": 8}),
                    make_cue_env),
        "DrQv2EF-latent": (sb3_ef.DrQv2EF, dict(drqv2, policy_kwargs=latent, beta=0.7, babbling_steps=0),
                           make_cue_env),
        "SEAR": (sb3_ef.SEAR, {"buffer_size": 500, "batch_size": 8, "learning_starts": 16, "train_freq": 1,
                                   "policy_kwargs": {**PLAIN_POLICY, "features_dim": 64}}, toy),
        "CURL": (sb3_ef.CURL, dict(SB3_COMMON, crop_size=28, policy_kwargs={"net_arch": [32, 32]}), make_cue_env),
        "SACEF": (sb3_ef.SACEF, dict(SB3_COMMON, policy_kwargs=SB3_POLICY, agent_dim=8, **EF_ARGS,
                                     ef_kwargs={"rollout_hidden_dims": (16,), "decoder_channels": 8}),
                  lambda: make_cue_env(size=64)),
        "TD3EF": (sb3_ef.TD3EF, dict(SB3_COMMON, policy_kwargs=SB3_POLICY, agent_dim=8, **EF_ARGS,
                                     ef_kwargs={"rollout_hidden_dims": (16,), "decoder_channels": 8}),
                  lambda: make_cue_env(size=64)),
        "TQCEF": (sb3_ef.TQCEF, dict(SB3_COMMON, policy_kwargs=SB3_POLICY, agent_dim=8, **EF_ARGS,
                                     ef_kwargs={"rollout_hidden_dims": (16,), "decoder_channels": 8}),
                  lambda: make_cue_env(size=64)),
        "TDMPC2": (sb3_ef.TDMPC2, {"buffer_size": 500, "batch_size": 8, "learning_starts": 16,
                                       "policy_kwargs": TDMPC2_TINY}, lambda: make_cue_env(size=64)),
        "TDMPC2EF": (sb3_ef.TDMPC2EF, {"buffer_size": 500, "batch_size": 8, "learning_starts": 16, "ef_horizon": 3,
                                           "babbling_steps": 8, "beta": 0.7, "policy_kwargs": TINY_EF_POLICY},
                     lambda: make_cue_env(size=64)),
    }


def fingerprint(name: str, algorithm: type, kwargs: dict, make) -> dict[str, th.Tensor]:
    th.manual_seed(0)
    np.random.seed(0)
    model = algorithm("CnnPolicy", make(), seed=0, device="cpu", **kwargs)
    records: list[float] = []
    logger = configure(None, [])
    original = logger.record

    def record(key, value, exclude=None):
        if key.startswith("train/") and isinstance(value, float):
            records.append(value)
        original(key, value, exclude)

    logger.record = record  # type: ignore[method-assign]
    model.set_logger(logger)
    model.learn(STEPS)
    state = {f"param/{key}": value.detach().clone() for key, value in model.policy.state_dict().items()}
    auxiliary = getattr(model, "auxiliary_module", None)
    if auxiliary is not None:
        state.update({f"aux/{key}": value.detach().clone() for key, value in auxiliary.state_dict().items()})
    state["logs"] = th.tensor(records, dtype=th.float64)
    return state


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("out")
    parser.add_argument("--against")
    parser.add_argument("--only", nargs="*")
    args = parser.parse_args()
    th.set_num_threads(1)
    results = {}
    for name, (algorithm, kwargs, make) in cases().items():
        if args.only and name not in args.only:
            continue
        results[name] = fingerprint(name, algorithm, kwargs, make)
        print(name, "done", flush=True)
    th.save(results, args.out)
    if args.against:
        before = th.load(args.against)
        for name, state in results.items():
            old = before[name]
            keys = set(state) | set(old)
            diffs = {}
            for key in sorted(keys):
                if key not in state or key not in old:
                    diffs[key] = "missing on one side"
                elif state[key].shape != old[key].shape:
                    diffs[key] = f"shape {tuple(old[key].shape)} -> {tuple(state[key].shape)}"
                elif not th.equal(state[key], old[key]):
                    diffs[key] = f"max diff {(state[key].double() - old[key].double()).abs().max().item():.3g}"
            print(f"{name}: {diffs if diffs else 'bit for bit equal'}")


if __name__ == "__main__":
    main()
