"""rl-zoo3's run folders read as evaluation records, so ``sb3-ef analyze results logs`` works after training."""

from __future__ import annotations

import inspect
import os
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np

from sb3_ef import registry
from sb3_ef.analysis._optional import require

if TYPE_CHECKING:
    import pandas as pd

EVALUATIONS_FILE = "evaluations.npz"
#: ``<env>_<n>``, with the ``_<uuid>`` that rl-zoo3's ``--uuid`` appends.
RUN_FOLDER = re.compile(r"^(?P<env>.+)_(?P<run>\d+)(?:_[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12})?$")
MAKE_ENV = "sb3_ef.envs.factory:make_env"


def _load_yaml(path: Path) -> Any:
    import yaml  # rl-zoo3 writes OrderedDicts with Python tags, hence the unsafe loader (files of the user's own run)

    with open(path) as file:
        return yaml.load(file, Loader=yaml.UnsafeLoader)


def _args_file(run_folder: str | os.PathLike) -> Path | None:
    """The run's ``<env>/args.yml``, or ``None`` without exactly one."""
    args_files = sorted(Path(run_folder).glob("*/args.yml"))
    return args_files[0] if len(args_files) == 1 else None


def recorded_args(run_folder: str | os.PathLike) -> dict[str, Any]:
    """The command line rl-zoo3 recorded for the run (``<env>/args.yml``), or ``{}`` without exactly one."""
    args_file = _args_file(run_folder)
    return dict(_load_yaml(args_file) or {}) if args_file else {}


def recorded_env_kwargs(run_folder: str | os.PathLike) -> dict[str, Any]:
    """The env options of an rl-zoo3 run: ``--env-kwargs`` of ``args.yml`` over the config entry's, as rl-zoo3 has."""
    args = recorded_args(run_folder)
    if args.get("env_kwargs"):
        return dict(args["env_kwargs"])
    args_file = _args_file(run_folder)
    config_path = args_file.with_name("config.yml") if args_file else None
    if config_path is None or not config_path.is_file():
        return {}
    entry = dict(_load_yaml(config_path) or [])  # rl-zoo3 writes a list of pairs
    recorded = entry.get("env_kwargs") or {}
    if isinstance(recorded, str):  # rl-zoo3 evaluates strings such as "dict(size=64)"
        recorded = eval(recorded, {"__builtins__": {}, "dict": dict})
    return dict(recorded)


def env_id_of_folder(env_name: str) -> str:
    """The registered env id whose rl-zoo3 folder name is ``env_name`` (``dmc-cheetah-run-v0``), else ``env_name``."""
    import sb3_ef  # noqa: F401  (registers the pixel envs)

    matches = [env_id for env_id in gym.registry if env_id.replace("/", "-") == env_name]
    return matches[0] if len(matches) == 1 else env_name


def action_repeat_of(env_id: str, env_kwargs: dict[str, Any]) -> int:
    """A run's action repeat: its recorded ``action_repeat``, else the registered env's (``make_env``'s default)."""
    if "action_repeat" in env_kwargs:
        return int(env_kwargs["action_repeat"])
    spec = gym.registry.get(env_id)
    if spec is None or spec.entry_point != MAKE_ENV:
        return 1
    from sb3_ef.envs.factory import make_env

    return int(spec.kwargs.get("action_repeat", inspect.signature(make_env).parameters["action_repeat"].default))


def algorithm_name(zoo_key: str) -> str:
    """The class name of an sb3-ef or rl-zoo3 algorithm key (``drqv2_ef`` -> ``DrQv2EF``), else the key itself."""
    if zoo_key in registry.ALGORITHMS:
        return registry.ALGORITHMS[zoo_key].class_name
    try:
        from rl_zoo3.utils import ALGOS
    except ImportError:
        return zoo_key
    return ALGOS[zoo_key].__name__ if zoo_key in ALGOS else zoo_key


def _evaluations(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``timesteps``, per-evaluation returns and successes of an ``evaluations.npz``, checked."""
    try:
        with np.load(path) as file:
            arrays = {name: file[name] for name in file.files}
    except (OSError, ValueError, EOFError) as error:
        raise ValueError(f"{path} is not a readable evaluations.npz ({type(error).__name__}: {error})") from error
    missing = [name for name in ("timesteps", "results") if name not in arrays]
    if missing:
        raise ValueError(f"{path}: expected rl-zoo3's EvalCallback arrays timesteps and results, missing {missing}")
    timesteps, results = arrays["timesteps"], arrays["results"]
    successes = arrays.get("successes")
    if results.ndim != 2 or len(results) != len(timesteps) or not np.issubdtype(results.dtype, np.number):
        raise ValueError(
            f"{path}: expected results of shape (evaluations, episodes) = ({len(timesteps)}, n), numbers, got "
            f"shape {results.shape} of {results.dtype}"
        )
    if successes is not None and (successes.size == 0 or len(successes) != len(timesteps)):
        successes = None  # rl-zoo3 saves an empty array for envs that report no success
    return timesteps, results, successes


def zoo_run_records(run_folder: str | os.PathLike, action_repeat: int | None = None) -> pd.DataFrame:
    """The evaluation records of one rl-zoo3 run folder; ``action_repeat`` replaces the run's recorded one."""
    pandas = require("pandas")
    from sb3_ef.analysis.records import RECORD_COLUMNS, record_row

    run_folder = Path(run_folder)
    timesteps, results, successes = _evaluations(run_folder / EVALUATIONS_FILE)
    match = RUN_FOLDER.match(run_folder.name)
    if match is None:
        raise ValueError(f"{run_folder}: expected an rl-zoo3 run folder named <env>_<n>, got {run_folder.name!r}")
    args = recorded_args(run_folder)
    task = str(args.get("env") or env_id_of_folder(match["env"]))
    seed = args.get("seed", int(match["run"]))
    repeat = action_repeat_of(task, recorded_env_kwargs(run_folder)) if action_repeat is None else action_repeat
    algo = algorithm_name(run_folder.parent.name)
    rows = [
        record_row(algo, task, seed, int(step), repeat, float(np.mean(returns)),
                   None if successes is None else float(np.mean(successes[index])))
        for index, (step, returns) in enumerate(zip(timesteps, results, strict=True))
    ]  # fmt: skip
    return pandas.DataFrame(rows, columns=list(RECORD_COLUMNS))


def is_zoo_run_folder(run_folder: str | os.PathLike) -> bool:
    """Whether ``run_folder`` is laid out as rl-zoo3 writes a run: named ``<env>_<n>``, with ``evaluations.npz``."""
    folder = Path(run_folder)
    return RUN_FOLDER.match(folder.name) is not None and (folder / EVALUATIONS_FILE).is_file()


def zoo_run_finished(run_folder: str | os.PathLike) -> bool:
    """Whether the rl-zoo3 run saved its final model (``<env>.zip`` in the run folder, written when training ends)."""
    match = RUN_FOLDER.match(Path(run_folder).name)
    return match is not None and (Path(run_folder) / f"{match['env']}.zip").is_file()
