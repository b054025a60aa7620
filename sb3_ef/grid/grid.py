"""A benchmark grid: algorithms x tasks x seeds expanded into checked, fully specified runs (docs/benchmark.md)."""

from __future__ import annotations

import fnmatch
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import yaml

import sb3_ef  # noqa: F401  (registers the environments)
from sb3_ef import registry
from sb3_ef.common.validation import did_you_mean
from sb3_ef.envs.factory import MAKE_ENV_SUITES
from sb3_ef.envs.registration import register_atari
from sb3_ef.zoo import config as zoo_config

FILE_KEYS = frozenset({"grids", "anchors"})
#: Keys of a grid block (those every block must give: REQUIRED_BLOCK_KEYS) and of an algorithm's mapping.
BLOCK_KEYS = frozenset(
    {"algorithms", "tasks", "seeds", "n_timesteps", "eval_freq", "eval_episodes", "checkpoint_freq", "env_kwargs",
     "hyperparams"}
)  # fmt: skip
REQUIRED_BLOCK_KEYS = frozenset({"algorithms", "tasks", "seeds", "eval_freq"})
ALGORITHM_KEYS = frozenset({"algo", "conf_file", "hyperparams", "env_kwargs", "steps_per_second"})

#: Zoo-config keys the runner reads itself; the rest go to the algorithm constructor.
RUNNER_KEYS = frozenset({"n_timesteps", "env_kwargs", "n_envs", "env_wrapper", "frame_stack"})

#: Keys whose ``lin_<initial value>`` strings rl-zoo3 turns into linear schedules.
LINEAR_SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf")

#: Zoo-config values rl-zoo3 evaluates when they are strings (``policy_kwargs: dict(...)``).
EVALUATED_KEYS = ("policy_kwargs", "replay_buffer_class", "replay_buffer_kwargs")

#: Where a grid's runs can execute: a local process pool or a Ray cluster.
BACKENDS = ("local", "ray")


class GridError(ValueError):
    """Every problem found in a grid, one line each, each naming its block or row (``problems``)."""

    def __init__(self, problems: Sequence[str]):
        super().__init__("\n".join(problems))
        self.problems = list(problems)


@dataclass(frozen=True)
class Algorithm:
    """One algorithm column of a grid.

    :param label: its name in the records, folders and tables (``drqv2_ef_beta1e-3``).
    :param algo: the registry key of the class, or a key of rl-zoo3's own algorithms for a baseline (``ppo``: SB3's PPO,
        its entries from rl-zoo3's hyperparameter files); default ``label``.
    :param conf_file: zoo-format YAML the entries come from; default ``zoo_configs/<algo>.yml``.
    :param hyperparams: overrides of the entries' values, in zoo syntax.
    :param env_kwargs: env options merged over the entries' and the grid's ``env_kwargs``.
    :param steps_per_second: expected agent steps per second, for time estimates only.
    """

    label: str
    algo: str = ""
    conf_file: str | None = None
    hyperparams: Mapping[str, Any] = field(default_factory=dict)
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)
    steps_per_second: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "algo", self.algo or self.label)
        algorithm_class(str(self.algo), f"Algorithm {self.label!r}: algo")  # a known key
        if not self.label or "/" in self.label or self.label != self.label.strip():
            raise ValueError(
                f"Algorithm label must be a non-empty name without '/' or spaces around, got {self.label!r}"
            )
        _check_mapping(f"Algorithm {self.label!r}: 'hyperparams'", self.hyperparams)
        _check_mapping(f"Algorithm {self.label!r}: 'env_kwargs'", self.env_kwargs)


@dataclass(frozen=True)
class RunSpec:
    """Everything one run needs, picklable for a worker process or a Ray task (``hyperparams`` in zoo syntax)."""

    label: str
    algo: str
    task: str
    seed: int
    n_timesteps: int
    eval_freq: int
    eval_episodes: int
    checkpoint_freq: int
    hyperparams: Mapping[str, Any] = field(default_factory=dict)
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)
    steps_per_second: float | None = None
    n_envs: int = 1
    env_wrapper: Any = None
    frame_stack: int | None = None

    @property
    def run_id(self) -> str:
        """``<label>/<task with '/' as '-'>_s<seed>``: unique in a grid, the run's path below the results."""
        return f"{self.label}/{self.task.replace('/', '-')}_s{self.seed}"

    @property
    def action_repeat(self) -> int:
        """Env frames per agent step: ``make_env``'s default 2 unless ``env_kwargs`` says otherwise; SB3's
        ``AtariWrapper`` in ``env_wrapper`` skips its ``frame_skip`` (4); 1 otherwise."""
        if self.task.startswith(MAKE_ENV_SUITES):
            return int(self.env_kwargs.get("action_repeat", 2))
        wrappers = self.env_wrapper if isinstance(self.env_wrapper, list) else [self.env_wrapper]
        for wrapper in wrappers:
            name, kwargs = next(iter(wrapper.items())) if isinstance(wrapper, dict) else (wrapper, None)
            if str(name).endswith("AtariWrapper"):
                return int((kwargs or {}).get("frame_skip", 4))
        return 1

    @property
    def vectorized(self) -> bool:
        """Whether the run's envs are built as rl-zoo3 builds them (``n_envs`` > 1, an ``env_wrapper`` or a
        ``frame_stack``), not as one env given to the algorithm."""
        return self.n_envs > 1 or self.env_wrapper is not None or bool(self.frame_stack)


def algorithm_class(algo: str, argument: str = "algo") -> type:
    """The class of a grid's ``algo``: a key of sb3-ef's registry, else of rl-zoo3's own algorithms (baselines)."""
    if algo in registry.ALGORITHMS:
        return registry.entry(algo).algorithm_class
    from rl_zoo3 import ALGOS

    if algo in ALGOS:
        return ALGOS[algo]
    zoo = sorted(set(ALGOS) - set(registry.ALGORITHMS))
    raise ValueError(
        f"{argument} {algo!r}{did_you_mean(str(algo), [*registry.ALGORITHMS, *zoo])} is not a known algorithm: "
        f"expected one of sb3-ef's {', '.join(registry.ALGORITHMS)} or rl-zoo3's {', '.join(zoo)}"
    )


def config_path(algo: str) -> Path:
    """The default zoo file of ``algo``: sb3-ef's ``zoo_configs/<algo>.yml``, or rl-zoo3's own for its algorithms."""
    if algo in registry.ALGORITHMS:
        return zoo_config.default_config_path(algo)
    import rl_zoo3

    return Path(rl_zoo3.__file__).parent / "hyperparams" / f"{algo}.yml"


def resolve_task(task: str) -> str:
    """The registered gymnasium id for ``task``: itself, or with ``-v0`` appended (``dmc/cartpole-balance``)."""
    if not isinstance(task, str):
        raise ValueError(f"A task must be a gymnasium id (a string), got {task!r}")
    register_atari(task)
    for candidate in (task, f"{task}-v0"):
        if candidate in gym.envs.registry:
            return candidate
    raise ValueError(
        f"Unknown task {task!r}{did_you_mean(task, gym.envs.registry)}: expected a registered id such as "
        "'dmc/cartpole-balance-v0', 'toy/agent-v0' or 'PongNoFrameskip-v4'"
    )


def _unknown_keys(unknown: Iterable[str], expected: Iterable[str]) -> str:
    """``'eval_frq' (did you mean 'eval_freq'?), 'x'`` for a message naming unknown keys."""
    expected = sorted(expected)
    return ", ".join(f"{key!r}{did_you_mean(str(key), expected)}" for key in sorted(unknown, key=str))


def _algorithms(value: Any) -> list[Algorithm]:
    if isinstance(value, str) or not isinstance(value, (Sequence, Mapping)) or not value:
        raise ValueError(
            f"'algorithms' must be a non-empty list of zoo keys or a mapping label -> options, got {value!r}"
        )
    if not isinstance(value, Mapping):
        algorithms = [item if isinstance(item, Algorithm) else Algorithm(str(item)) for item in value]
        twice = _repeated([algorithm.label for algorithm in algorithms])
        if twice is not None:
            raise ValueError(f"'algorithms' lists {twice!r} twice: give each variant its own label (label -> options)")
        return algorithms
    algorithms = []
    for label, options in value.items():
        options = options or {}
        if not isinstance(options, Mapping):
            raise ValueError(f"Algorithm {label!r}: expected a mapping of options, got {options!r}")
        unknown = set(options) - ALGORITHM_KEYS
        if unknown:
            raise ValueError(
                f"Algorithm {label!r}: unknown key(s) {_unknown_keys(unknown, ALGORITHM_KEYS)}; expected "
                f"{', '.join(sorted(ALGORITHM_KEYS))}"
            )
        algorithms.append(Algorithm(str(label), **options))
    return algorithms


def _seeds(value: Any) -> list[int]:
    if isinstance(value, int) and not isinstance(value, bool) and value > 0:
        return list(range(value))
    if isinstance(value, Sequence) and value and all(isinstance(s, int) and not isinstance(s, bool) for s in value):
        if _repeated(value) is not None:
            raise ValueError(f"'seeds' lists seed {_repeated(value)} twice ({list(value)}): one run per seed")
        return list(value)
    raise ValueError(f"'seeds' must be a positive count or a non-empty list of ints, got {value!r}")


def _repeated(items: Sequence[Any]) -> Any:
    """The first item of ``items`` that occurs twice, or ``None``."""
    return next((item for item in items if items.count(item) > 1), None)


def _check_mapping(name: str, value: Any) -> None:
    if not isinstance(value, Mapping):
        raise ValueError(f"{name} must be a mapping of names to values, got {value!r}")


def _positive(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or int(value) != value or value < 1:
        raise ValueError(f"{name!r} must be a positive integer, got {value!r}")
    return int(value)


def _entry(algorithm: Algorithm, task: str, overrides: Mapping[str, Any]) -> dict[str, Any]:
    """The zoo entry for ``task`` with ``overrides`` applied, every key checked."""
    algo_class = algorithm_class(algorithm.algo)
    path = algorithm.conf_file or config_path(algorithm.algo)
    entries = zoo_config.load_config(path)
    if algorithm.algo in registry.ALGORITHMS:  # rl-zoo3's own files name envs of packages not imported here
        zoo_config.validate_config(algorithm.algo, algo_class, entries, source=os.fspath(path))
    zoo_config.check_keys(algorithm.algo, algo_class, overrides, where=f"hyperparams of {algorithm.label!r}")
    entry = {**zoo_config.select_entry(entries, task), **overrides}
    unsupported = set(entry) & (zoo_config.ZOO_KEYS - RUNNER_KEYS)
    if unsupported:
        raise ValueError(f"{algorithm.label} on {task}: key(s) {sorted(unsupported)} are not supported by the runner")
    _positive("n_envs", entry.get("n_envs", 1))
    try:
        constructor_kwargs(entry)
    except Exception as error:  # a zoo string that does not evaluate: name the run it belongs to
        raise ValueError(f"{algorithm.label} on {task}: {type(error).__name__}: {error}") from error
    return entry


def constructor_kwargs(hyperparams: Mapping[str, Any]) -> dict[str, Any]:
    """A zoo entry's constructor arguments, strings of :data:`EVALUATED_KEYS` evaluated as rl-zoo3 does."""
    from rl_zoo3 import exp_manager
    from rl_zoo3.utils import linear_schedule

    from sb3_ef.zoo.registration import config_namespace

    namespace = {**vars(exp_manager), **config_namespace()}
    kwargs = {
        key: eval(value, namespace) if key in EVALUATED_KEYS and isinstance(value, str) else value
        for key, value in hyperparams.items()
        if key not in RUNNER_KEYS
    }
    for key in LINEAR_SCHEDULE_KEYS:
        if isinstance(kwargs.get(key), str) and kwargs[key].startswith("lin_"):
            kwargs[key] = linear_schedule(float(kwargs[key][len("lin_") :]))
    return kwargs


def grid_runs(
    algorithms: Iterable[str | Algorithm] | Mapping[str, Mapping[str, Any]],
    tasks: Iterable[str],
    seeds: int | Sequence[int],
    eval_freq: int,
    eval_episodes: int = 10,
    n_timesteps: int | None = None,
    checkpoint_freq: int | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    hyperparams: Mapping[str, Any] | None = None,
) -> list[RunSpec]:
    """Expand algorithms x tasks x seeds into runs, seed-major (a grid stopped part-way has whole seeds).

    :param algorithms: zoo keys, :class:`Algorithm` objects, or a mapping label -> :class:`Algorithm` options.
    :param tasks: gymnasium ids (the ``-v0`` may be left out).
    :param seeds: a count n (seeds 0..n-1) or the list of seeds.
    :param eval_freq: agent steps between evaluations.
    :param eval_episodes: episodes per evaluation.
    :param n_timesteps: agent steps per run; default each entry's ``n_timesteps``.
    :param checkpoint_freq: agent steps between checkpoints, a multiple of ``eval_freq`` (default ``eval_freq``).
    :param env_kwargs: env options merged over each entry's ``env_kwargs``.
    :param hyperparams: overrides for every algorithm (before each algorithm's own).
    """
    eval_freq = _positive("eval_freq", eval_freq)
    eval_episodes = _positive("eval_episodes", eval_episodes)
    checkpoint_freq = _positive("checkpoint_freq", checkpoint_freq or eval_freq)
    if checkpoint_freq % eval_freq:
        raise ValueError(f"checkpoint_freq ({checkpoint_freq}) must be a multiple of eval_freq ({eval_freq})")
    if not isinstance(tasks, (str, Sequence)):
        raise ValueError(f"'tasks' must be a list of gymnasium ids, got {tasks!r}")
    for name, value in (("env_kwargs", env_kwargs), ("hyperparams", hyperparams)):
        _check_mapping(repr(name), value or {})
    written = [tasks] if isinstance(tasks, str) else list(tasks)
    tasks = [resolve_task(task) for task in written]
    if not tasks:
        raise ValueError("'tasks' must name at least one task")
    twice = _repeated(tasks)
    if twice is not None:
        given = " and ".join(repr(name) for name, task in zip(written, tasks, strict=True) if task == twice)
        raise ValueError(f"'tasks' names {twice} twice ({given}; the '-v0' may be left out)")
    runs_of_seed: list[dict[str, Any]] = []  # the runs of one seed, as RunSpec arguments without the seed
    problems: dict[str, None] = {}  # each once (a bad override is one problem, not one per task)
    for algorithm in _algorithms(algorithms):
        for task in tasks:
            try:
                entry = _entry(algorithm, task, {**(hyperparams or {}), **algorithm.hyperparams})
                steps = _positive("n_timesteps", n_timesteps if n_timesteps is not None else entry["n_timesteps"])
                if eval_freq > steps:
                    raise ValueError(
                        f"eval_freq ({eval_freq}) exceeds n_timesteps ({steps}) of {algorithm.label} on {task}"
                    )
                n_envs = entry.get("n_envs", 1)
                if eval_freq % n_envs:
                    raise ValueError(
                        f"eval_freq ({eval_freq}) of {algorithm.label} on {task} must be a multiple of its n_envs "
                        f"({n_envs}): each env step is n_envs agent steps"
                    )
            except ValueError as error:
                problems[str(error)] = None
                continue
            runs_of_seed.append({
                "label": algorithm.label, "algo": algorithm.algo, "task": task, "n_timesteps": steps,
                "eval_freq": eval_freq, "eval_episodes": eval_episodes, "checkpoint_freq": checkpoint_freq,
                "hyperparams": {key: value for key, value in entry.items() if key not in RUNNER_KEYS},
                "env_kwargs": {**(entry.get("env_kwargs") or {}), **(env_kwargs or {}), **algorithm.env_kwargs},
                "steps_per_second": algorithm.steps_per_second, "n_envs": n_envs,
                "env_wrapper": entry.get("env_wrapper"), "frame_stack": entry.get("frame_stack"),
            })  # fmt: skip
    if problems:
        raise GridError(list(problems))
    return [RunSpec(seed=seed, **arguments) for seed in _seeds(seeds) for arguments in runs_of_seed]


def check_unique(runs: Sequence[RunSpec], places: Sequence[str] | None = None) -> None:
    """Raise ``ValueError`` naming a run id that occurs twice (two runs would share one results folder) and the
    ``places`` of the two runs (default: their positions)."""
    places = places or [f"run {index} of the grid" for index in range(1, len(runs) + 1)]
    first: dict[str, str] = {}
    for run, place in zip(runs, places, strict=True):
        if first.setdefault(run.run_id, place) != place:
            raise ValueError(
                f"{run.label} on {run.task} with seed {run.seed} is {first[run.run_id]} and {place}: the two runs "
                f"would share one results folder ({run.run_id}); give {run.label} another label in one of them"
            )


def select_runs(runs: Sequence[RunSpec], patterns: Sequence[str]) -> list[RunSpec]:
    """The runs whose id matches one of the shell-style ``patterns`` (``drqv2_ef/*``, ``*_s0``), in grid order."""
    selected = [run for run in runs if any(fnmatch.fnmatchcase(run.run_id, pattern) for pattern in patterns)]
    if not selected:
        raise ValueError(f"No run id matches {list(patterns)}; ids look like {runs[0].run_id!r}")
    return selected


def _yaml_error(error: yaml.MarkedYAMLError) -> str:
    """``, line 3, column 10: not valid YAML: <problem> (<context> at line 2, column 18)``."""

    def at(mark: Any) -> str:
        return f"line {mark.line + 1}, column {mark.column + 1}"

    where = f", {at(error.problem_mark)}" if error.problem_mark is not None else ""
    text = f"{where}: not valid YAML: {error.problem or error.context}"
    if error.problem and error.context and error.context_mark is not None:
        text += f" ({error.context} at {at(error.context_mark)})"
    return text


def read_grid_file(path: str | os.PathLike) -> list[dict[str, Any]]:
    """The blocks of a grid file, their keys checked (nothing heavy is imported)."""
    try:
        with open(path) as file:
            document = yaml.safe_load(file)
    except yaml.MarkedYAMLError as error:
        raise ValueError(f"{path}{_yaml_error(error)}") from None
    except yaml.YAMLError as error:
        raise ValueError(f"{path}: not valid YAML: {error}") from None
    except UnicodeDecodeError as error:
        raise ValueError(f"{path}: not a text file ({error.reason} at byte {error.start})") from None
    if not isinstance(document, dict) or not isinstance(document.get("grids"), list) or not document["grids"]:
        raise ValueError(f"{path}: expected a mapping with a non-empty list 'grids' of blocks, got {document!r:.80}")
    if set(document) - FILE_KEYS:
        raise ValueError(
            f"{path}: unknown top-level key(s) {_unknown_keys(set(document) - FILE_KEYS, FILE_KEYS)}; expected "
            f"{', '.join(sorted(FILE_KEYS))}"
        )
    for index, block in enumerate(document["grids"]):
        where = f"{path}, grids[{index}]"
        if not isinstance(block, dict):
            raise ValueError(f"{where}: expected a mapping, got {block!r}")
        problems = []
        if set(block) - BLOCK_KEYS:
            problems.append(f"unknown key(s) {_unknown_keys(set(block) - BLOCK_KEYS, BLOCK_KEYS)}")
        if REQUIRED_BLOCK_KEYS - set(block):
            problems.append(f"missing key(s) {', '.join(sorted(REQUIRED_BLOCK_KEYS - set(block)))}")
        if problems:
            raise ValueError(f"{where}: {'; '.join(problems)} (keys of a block: {', '.join(sorted(BLOCK_KEYS))})")
    return document["grids"]


def load_grid(path: str | os.PathLike) -> list[RunSpec]:
    """Read a grid file and expand every block; a :class:`GridError` names every problem of every block."""
    runs, places, problems = [], [], []
    for index, block in enumerate(read_grid_file(path)):
        try:
            block_runs = grid_runs(**block)
        except GridError as error:
            problems += [f"{path}, grids[{index}]: {problem}" for problem in error.problems]
        except ValueError as error:
            problems.append(f"{path}, grids[{index}]: {error}")
        else:
            runs += block_runs
            places += [f"a run of {path}, grids[{index}]"] * len(block_runs)
    if problems:
        raise GridError(problems)
    check_unique(runs, places)  # a block repeats no run: two blocks may
    return runs
