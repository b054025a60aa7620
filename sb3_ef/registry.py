"""The algorithm registry: each key mapped to its class (imported on first use) and what the workbench does with it.
A new algorithm is one entry here, a zoo config and its package."""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

from sb3_ef.common.validation import did_you_mean
from sb3_ef.envs.factory import SUITE_OPTIONS

#: Name prefixes of the suites :func:`sb3_ef.make_env` builds (it repeats actions); other ids go through ``gym.make``.
MAKE_ENV_SUITES = tuple(f"{suite}/" for suite in SUITE_OPTIONS)
#: The grid run function and row check of the algorithms SB3's ``learn`` trains.
SB3_GRID_RUN = "sb3_ef.grid.run:train_sb3"
SB3_GRID_CHECK = "sb3_ef.grid.checks:check_sb3_row"


def import_target(target: str) -> Any:
    """The object a ``"module:attribute"`` path names, imported now."""
    module, _, attribute = target.partition(":")
    return getattr(importlib.import_module(module), attribute)


@dataclass(frozen=True)
class AlgorithmEntry:
    """What the workbench needs of one algorithm.

    :param key: the name in commands, configs and grids (``drqv2_ef``).
    :param target: the class, as ``"module:Class"``.
    :param paper: a method or baseline of the Ego-Foresight paper (its zoo config holds the paper's tasks).
    :param ef: trains Ego-Foresight: ``sb3-ef analyze model`` shows its predictions and saliency.
    :param own_exploration: explores with its own noise (rl-zoo3's SB3 action-noise keys are refused).
    :param sampler: its Optuna sampler for ``sb3-ef optimize`` (``"module:function"``), if it has one.
    :param grid_run: the function that trains one ``sb3-ef benchmark`` row (as :func:`sb3_ef.grid.run.train_sb3`).
    :param grid_check: the function that checks one row before anything trains (as ``check_sb3_row``).
    :param zoo_run: the ``train`` and ``enjoy`` functions of an algorithm rl-zoo3 cannot train; ``None``: rl-zoo3's.
    :param warm_start: an offline-pretrained encoder and EF can be copied into it; ``sb3-ef collect`` acts with it.
    :param legacy_policy_module: the policy module of its sb3-ef 0.1.0 files (``sb3-ef upgrade``), if any.
    :param zoo_frame_stack: takes frames of any channel count stacked by rl-zoo3's ``frame_stack`` key (Atari's grey
        frames); the others read RGB frames stacked inside the env.
    """

    key: str
    target: str
    paper: bool = False
    ef: bool = False
    own_exploration: bool = False
    sampler: str | None = None
    grid_run: str = SB3_GRID_RUN
    grid_check: str = SB3_GRID_CHECK
    zoo_run: tuple[str, str] | None = None
    warm_start: bool = False
    legacy_policy_module: str | None = None
    zoo_frame_stack: bool = False

    @property
    def class_name(self) -> str:
        """The class's name, as records and saved files write it (``DrQv2EF``)."""
        return self.target.rpartition(":")[2]

    @property
    def algorithm_class(self) -> type[Any]:
        """The class (imported now)."""
        return import_target(self.target)

    @property
    def rl_zoo3(self) -> bool:
        """Whether rl-zoo3 trains it (registered in its ``ALGOS``)."""
        return self.zoo_run is None


def _paper_host(key: str, target: str, ef: bool) -> AlgorithmEntry:
    """A host of the paper (DrQ-v2, TD-MPC2), with or without EF: Optuna sampler ``sample_<key>_params``."""
    package = target.partition(":")[0]
    return AlgorithmEntry(
        key, target, paper=True, ef=ef, own_exploration=True, sampler=f"sb3_ef.zoo.hyperparams_opt:sample_{key}_params",
        warm_start=ef, legacy_policy_module=f"{package}.policies",
    )  # fmt: skip


ALGORITHMS: dict[str, AlgorithmEntry] = {entry.key: entry for entry in (
    _paper_host("drqv2_ef", "sb3_ef.drqv2:DrQv2EF", ef=True),
    _paper_host("drqv2", "sb3_ef.drqv2:DrQv2", ef=False),
    _paper_host("tdmpc2_ef", "sb3_ef.tdmpc2:TDMPC2EF", ef=True),
    _paper_host("tdmpc2", "sb3_ef.tdmpc2:TDMPC2", ef=False),
    AlgorithmEntry("sear", "sb3_ef.sear:SEAR", paper=True, own_exploration=True),
    AlgorithmEntry("curl", "sb3_ef.curl:CURL", paper=True, own_exploration=True),
    AlgorithmEntry("sac_ef", "sb3_ef.sb3_hosts:SACEF", ef=True, legacy_policy_module="stable_baselines3.sac.policies"),
    AlgorithmEntry("td3_ef", "sb3_ef.sb3_hosts:TD3EF", ef=True, legacy_policy_module="stable_baselines3.td3.policies"),
    AlgorithmEntry("tqc_ef", "sb3_ef.sb3_hosts:TQCEF", ef=True, legacy_policy_module="sb3_contrib.tqc.policies"),
    AlgorithmEntry("ppo_ef", "sb3_ef.sb3_hosts:PPOEF", ef=True, own_exploration=True, zoo_frame_stack=True),
    AlgorithmEntry("a2c_ef", "sb3_ef.sb3_hosts:A2CEF", ef=True, own_exploration=True, zoo_frame_stack=True),
    AlgorithmEntry(
        "dreamerv3", "sb3_ef.dreamerv3:DreamerV3", paper=True, own_exploration=True,
        grid_run="sb3_ef.dreamerv3.grid_run:train_dreamerv3",
        grid_check="sb3_ef.dreamerv3.grid_run:check_dreamerv3_row",
        zoo_run=("sb3_ef.zoo.sheeprl_run:train_main", "sb3_ef.zoo.sheeprl_run:enjoy_main"),
    ),
)}  # fmt: skip


def entry(key: str, argument: str = "algo") -> AlgorithmEntry:
    """The entry of ``key``; a ``ValueError`` names ``argument`` (where the key came from) and the known keys."""
    if key not in ALGORITHMS:
        raise ValueError(
            f"{argument} {key!r}{did_you_mean(str(key), ALGORITHMS)} is not a known algorithm: expected one of "
            f"{', '.join(ALGORITHMS)}"
        )
    return ALGORITHMS[key]


def keys(**capabilities: bool) -> tuple[str, ...]:
    """The keys whose entries have the given attribute values, in registry order (``keys(ef=True)``)."""
    wanted = capabilities.items()
    return tuple(key for key, item in ALGORITHMS.items() if all(getattr(item, name) == value for name, value in wanted))


def by_class_name(name: str) -> AlgorithmEntry | None:
    """The entry of the class named ``name`` (as a saved file records it), or ``None``."""
    return next((item for item in ALGORITHMS.values() if item.class_name == name), None)
