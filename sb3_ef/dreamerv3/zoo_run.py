"""``sb3-ef train`` and ``enjoy`` with ``--algo dreamerv3``: sheeprl's loop with rl-zoo3's arguments and folders."""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from sb3_ef import registry
from sb3_ef.common.interrupt import Interrupted
from sb3_ef.grid.grid import RunSpec
from sb3_ef.grid.run import RunPaths, build_env
from sb3_ef.zoo import config
from sb3_ef.zoo.options import ENJOY_OPTIONS, TRAIN_OPTIONS, check_enjoy_argv, check_train_argv, merge_train_argv
from sb3_ef.zoo.records import finish_run, run_result_path
from sb3_ef.zoo.resume import ARGV_FILE, recorded_argv, with_seed

#: The train options these runs take; rl-zoo3's others (Optuna, vectorised envs, -i, tracking) do not apply.
TRAIN_SUPPORTED = frozenset(
    {"--algo", "--env", "--n-timesteps", "--eval-freq", "--eval-episodes", "--save-freq", "--log-folder", "--seed",
     "--device", "--hyperparams", "--env-kwargs", "--conf-file", "--num-threads", "--verbose", "--gym-packages",
     "--resume", "--keep-checkpoints"}
)  # fmt: skip
ENJOY_SUPPORTED = frozenset(
    {"--algo", "--env", "--folder", "--exp-id", "--n-timesteps", "--deterministic", "--seed", "--device",
     "--env-kwargs", "--no-render", "--num-threads", "--verbose", "--gym-packages"}
)  # fmt: skip
#: rl-zoo3's defaults where these runs use them.
DEFAULT_EVAL_FREQ, DEFAULT_EVAL_EPISODES, DEFAULT_ENJOY_STEPS = 25_000, 5, 1000


def _refuse_unsupported(args: argparse.Namespace, options: Sequence[Any], supported: frozenset[str], how: str) -> None:
    """Raise ``ValueError`` naming the first given option that ``supported`` lacks."""
    for option in options:
        name = next(name for name in option.names if name.startswith("--"))
        if name not in supported and getattr(args, name[2:].replace("-", "_"), None) not in (None, False):
            raise ValueError(
                f"{option.names[0]} is not supported for --algo {args.algo}, which {how}; its options: "
                f"{', '.join(sorted(supported))}"
            )


def _pairs(items: Sequence[str] | None, option: str) -> dict[str, Any]:
    """rl-zoo3's ``key:value`` items, values evaluated as rl-zoo3 evaluates them."""
    from sb3_ef.zoo.train import override_values

    return override_values(list(items or ()), option)


def _new_run_folder(log_folder: str, algo: str, env_name: str) -> Path:
    """``<log_folder>/<algo>/<env>_<n+1>``, as rl-zoo3 numbers its runs."""
    from rl_zoo3.utils import EnvironmentName, get_latest_run_id

    log_path = os.path.join(log_folder, algo)
    return Path(log_path) / f"{env_name}_{get_latest_run_id(log_path, EnvironmentName(env_name)) + 1}"


def _write_run_files(params: Path, args: argparse.Namespace, entry: dict[str, Any], argv: list[str]) -> None:
    """``args.yml``, ``config.yml`` (the entry as rl-zoo3 writes it: a list of pairs) and ``train_argv.json``."""
    params.mkdir(parents=True, exist_ok=True)
    recorded = {"algo": args.algo, "env": args.env, "seed": args.seed, "env_kwargs": entry.get("env_kwargs", {})}
    (params / "args.yml").write_text(yaml.safe_dump(recorded))
    (params / "config.yml").write_text(yaml.safe_dump([[key, entry[key]] for key in sorted(entry)]))
    (params / ARGV_FILE).write_text(json.dumps(with_seed(argv, args.seed)))


def run_spec(args: argparse.Namespace) -> tuple[RunSpec, dict[str, Any]]:
    """The run of the parsed train arguments and its zoo entry (``--hyperparams`` and ``--env-kwargs`` over it)."""
    algo_class = registry.entry(args.algo).algorithm_class
    conf_file = args.conf_file or str(config.default_config_path(args.algo))
    entries = config.load_config(conf_file)
    config.validate_config(args.algo, algo_class, entries, source=conf_file)
    overrides = _pairs(args.hyperparams, "--hyperparams")
    config.check_keys(args.algo, algo_class, overrides, where="--hyperparams")
    entry = {**config.select_entry(entries, args.env), **overrides}
    entry["env_kwargs"] = {**(entry.get("env_kwargs") or {}), **_pairs(args.env_kwargs, "--env-kwargs")}
    if args.eval_freq is not None and args.eval_freq < 1:
        raise ValueError(
            f"--eval-freq {args.eval_freq} (no evaluation) does not apply to --algo {args.algo}, whose runs record an "
            f"evaluation every --eval-freq steps (default {DEFAULT_EVAL_FREQ})"
        )
    n_timesteps = args.n_timesteps or int(entry["n_timesteps"])
    spec = RunSpec(
        label=args.algo, algo=args.algo, task=args.env, seed=args.seed, n_timesteps=n_timesteps,
        eval_freq=args.eval_freq or DEFAULT_EVAL_FREQ, eval_episodes=args.eval_episodes or DEFAULT_EVAL_EPISODES,
        checkpoint_freq=args.save_freq if args.save_freq and args.save_freq > 0 else n_timesteps,  # -1: at the end
        hyperparams=entry, env_kwargs=entry["env_kwargs"],
    )  # fmt: skip
    return spec, entry


def train_main(argv: list[str]) -> None:
    """``sb3-ef train --algo dreamerv3`` (see the module docstring)."""
    import numpy as np

    from sb3_ef.dreamerv3.grid_run import train_dreamerv3

    args = check_train_argv(argv)
    folder = None
    if args.resume is not None:
        extra = [arg for arg in argv if arg not in ("--resume", args.resume)]
        folder = Path(args.resume)
        argv = merge_train_argv(recorded_argv(folder)[1], extra)
        args = check_train_argv(argv)
    _refuse_unsupported(args, TRAIN_OPTIONS, TRAIN_SUPPORTED, "trains in its own loop, not rl-zoo3's")
    if args.seed is None:
        args.seed = int(np.random.randint(2**31 - 1))
    spec, entry = run_spec(args)
    env_name = spec.task.replace("/", "-")
    folder = folder or _new_run_folder(args.log_folder or "logs", spec.algo, env_name)
    paths = RunPaths(folder / f"{env_name}.csv", folder / env_name, final_model=folder / f"{env_name}.zip")
    _write_run_files(paths.folder, args, entry, argv)
    run_result_path(folder, env_name).unlink(missing_ok=True)  # finished again only when it reaches its steps
    print(f"Log path: {folder}", flush=True)
    keep = args.keep_checkpoints if args.keep_checkpoints is not None else 2
    try:
        steps, _ = train_dreamerv3(spec, paths, args.num_threads or 1, args.device or "auto", keep)
    except Interrupted as interrupt:
        raise Interrupted(f"{interrupt}: continue with `sb3-ef train --resume {folder}`") from None
    finish_run(folder, env_name, steps)
    print(f"Saving to {paths.model}", flush=True)


def enjoy_main(argv: list[str]) -> None:
    """``sb3-ef enjoy --algo dreamerv3``: the run's final model acting ``-n`` steps, printed as rl-zoo3 prints."""
    args = check_enjoy_argv(argv)
    _refuse_unsupported(args, ENJOY_OPTIONS, ENJOY_SUPPORTED, "acts outside rl-zoo3")
    folder = args.folder or "rl-trained-agents"
    exp_id = args.exp_id or 0
    env_name = args.env.replace("/", "-")
    log_path = Path(folder) / args.algo
    run = (  # sb3_ef.zoo.enjoy checked that it exists
        log_path / f"{env_name}_{exp_id}"
        if exp_id
        else max(log_path.glob(f"{env_name}_[0-9]*"), key=lambda path: int(path.name.rsplit("_", 1)[1]))
    )
    model_path, args_path = run / f"{env_name}.zip", run / env_name / "args.yml"
    for path, written in ((model_path, "when the run finishes or is stopped by Ctrl-C"), (args_path, "at its start")):
        if not path.is_file():
            raise ValueError(f"Cannot enjoy the run {run}: {path} is missing (`sb3-ef train` writes it {written})")
    recorded = yaml.safe_load(args_path.read_text())
    env_kwargs = {**recorded.get("env_kwargs", {}), **_pairs(args.env_kwargs, "--env-kwargs")}
    spec = RunSpec(args.algo, args.algo, args.env, args.seed or 0, 1, 1, 1, 1, env_kwargs=env_kwargs)
    model = registry.entry(args.algo).algorithm_class.load(model_path, device=args.device or "auto")
    env = build_env(spec, seed=spec.seed)
    print(f"Loading {model_path}", flush=True)
    _act(model, env, args.n_timesteps or DEFAULT_ENJOY_STEPS, bool(args.deterministic))
    env.close()


def _act(model: Any, env: Any, steps: int, deterministic: bool) -> None:
    """Act ``steps`` steps, printing each finished episode's return and length."""
    observation, _ = env.reset(seed=0)
    episode_return, episode_length, state, start = 0.0, 0, None, True
    for _ in range(steps):
        action, state = model.predict(observation[None], state, [start], deterministic)
        observation, reward, terminated, truncated, _ = env.step(action[0])
        episode_return, episode_length, start = episode_return + float(reward), episode_length + 1, False
        if terminated or truncated:
            print(f"Episode Reward: {episode_return:.2f}\nEpisode Length {episode_length}", flush=True)
            observation, _ = env.reset()
            episode_return, episode_length, start = 0.0, 0, True
