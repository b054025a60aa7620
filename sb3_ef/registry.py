"""The algorithm registry, the one table of sb3-ef's algorithms: each key mapped to its class (named by import path,
imported on first use) and its facts. The workbench keeps its own per-key hooks (zoo run, sampler, grid run and
check) in the packages that call them; the library's tables (the root's names, ``POLICY_OWNERS``, ``EF_CLASSES``)
derive from this one."""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

from sb3_ef.common.names import did_you_mean


def import_target(target: str) -> Any:
    """The object a ``"module:attribute"`` path names, imported now."""
    module, _, attribute = target.partition(":")
    return getattr(importlib.import_module(module), attribute)


@dataclass(frozen=True)
class AlgorithmEntry:
    """One algorithm's facts.

    :param key: the name in commands, configs and grids (``drqv2_ef``).
    :param target: the class, as ``"module:Class"``.
    :param paper: a method or baseline of the Ego-Foresight paper (its zoo config holds the paper's tasks).
    :param ef: trains Ego-Foresight: ``sb3-ef analyze model`` shows its predictions and saliency.
    :param own_exploration: explores with its own noise (rl-zoo3's SB3 action-noise keys are refused).
    :param warm_start: an offline-pretrained encoder and EF can be copied into it; ``sb3-ef collect`` acts with it.
    :param legacy_policy_module: the policy module of its sb3-ef 0.1.0 files (``sb3-ef upgrade``), if any.
    :param workbench: its class is the workbench's (a wrapper of another project's agent), not the library's: the
        root ``sb3_ef`` does not export it.
    :param zoo_frame_stack: takes frames of any channel count stacked by rl-zoo3's ``frame_stack`` key (Atari's grey
        frames); the others read RGB frames stacked inside the env.
    """

    key: str
    target: str
    paper: bool = False
    ef: bool = False
    own_exploration: bool = False
    warm_start: bool = False
    legacy_policy_module: str | None = None
    workbench: bool = False
    zoo_frame_stack: bool = False

    @property
    def module(self) -> str:
        """The module that defines the class (``sb3_ef.drqv2``)."""
        return self.target.partition(":")[0]

    @property
    def class_name(self) -> str:
        """The class's name, as records and saved files write it (``DrQv2EF``)."""
        return self.target.rpartition(":")[2]

    @property
    def algorithm_class(self) -> type[Any]:
        """The class (imported now)."""
        return import_target(self.target)


def _paper_host(key: str, target: str, ef: bool) -> AlgorithmEntry:
    """A host of the paper (DrQ-v2, TD-MPC2), with or without EF."""
    policies = f"{target.partition(':')[0]}.policies"
    return AlgorithmEntry(
        key, target, paper=True, ef=ef, own_exploration=True, warm_start=ef, legacy_policy_module=policies
    )


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
    # sheeprl's Dreamer-v3 behind SB3's interface: a class of the workbench, which the library never imports.
    AlgorithmEntry("dreamerv3", "sb3_ef.dreamerv3:DreamerV3", paper=True, own_exploration=True, workbench=True),
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
