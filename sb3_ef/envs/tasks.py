"""Task names of the pixel environments, ``<suite>/<task>[-v0]``, and their parsing; no MuJoCo import."""

from __future__ import annotations

from typing import NamedTuple

from sb3_ef.common.validation import did_you_mean

#: dm-control suite tasks as (domain, task), in ``dm_control.suite.ALL_TASKS`` order (checked by the tests).
_DMC_SUITE_TASKS: tuple[tuple[str, str], ...] = (
    ("acrobot", "swingup"), ("acrobot", "swingup_sparse"), ("ball_in_cup", "catch"),
    ("cartpole", "balance"), ("cartpole", "balance_sparse"), ("cartpole", "swingup"),
    ("cartpole", "swingup_sparse"), ("cartpole", "two_poles"), ("cartpole", "three_poles"),
    ("cheetah", "run"), ("dog", "stand"), ("dog", "walk"), ("dog", "trot"), ("dog", "run"), ("dog", "fetch"),
    ("finger", "spin"), ("finger", "turn_easy"), ("finger", "turn_hard"), ("fish", "upright"), ("fish", "swim"),
    ("hopper", "stand"), ("hopper", "hop"), ("humanoid", "stand"), ("humanoid", "walk"), ("humanoid", "run"),
    ("humanoid", "run_pure_state"), ("humanoid_CMU", "stand"), ("humanoid_CMU", "walk"), ("humanoid_CMU", "run"),
    ("lqr", "lqr_2_1"), ("lqr", "lqr_6_2"), ("manipulator", "bring_ball"), ("manipulator", "bring_peg"),
    ("manipulator", "insert_ball"), ("manipulator", "insert_peg"), ("pendulum", "swingup"),
    ("point_mass", "easy"), ("point_mass", "hard"), ("quadruped", "walk"), ("quadruped", "run"),
    ("quadruped", "escape"), ("quadruped", "fetch"), ("reacher", "easy"), ("reacher", "hard"),
    ("stacker", "stack_2"), ("stacker", "stack_4"), ("swimmer", "swimmer6"), ("swimmer", "swimmer15"),
    ("walker", "stand"), ("walker", "walk"), ("walker", "run"),
)  # fmt: skip

#: Every DMC task name accepted after ``dmc/``, mapped to its dm-control (domain, task).
DMC_TASKS: dict[str, tuple[str, str]] = {
    f"{domain}-{task}".replace("_", "-"): (domain, task) for domain, task in _DMC_SUITE_TASKS
}

#: The domains of the Distracting Control Suite (Stone et al. 2021), the six its per-domain settings cover.
DISTRACTING_DOMAINS: tuple[str, ...] = ("ball_in_cup", "cartpole", "cheetah", "finger", "reacher", "walker")

#: Every task name accepted after ``dmc-distracting/``: the DMC tasks of :data:`DISTRACTING_DOMAINS`.
DISTRACTING_TASKS: dict[str, tuple[str, str]] = {
    name: pair for name, pair in DMC_TASKS.items() if pair[0] in DISTRACTING_DOMAINS
}

#: 12 DMC tasks that contain the paper's 10 (which two are extra is not known).
DMC_PAPER_TASKS: tuple[str, ...] = (
    "acrobot-swingup", "cartpole-swingup-sparse", "cheetah-run", "finger-spin", "finger-turn-easy",
    "finger-turn-hard", "quadruped-run", "quadruped-walk", "reacher-easy", "reacher-hard", "walker-run",
    "walker-walk",
)  # fmt: skip

#: Every Meta-World task name accepted after ``metaworld/`` (metaworld 3.x env name without ``-v3``).
METAWORLD_TASKS: tuple[str, ...] = (
    "assembly", "basketball", "bin-picking", "box-close", "button-press-topdown", "button-press-topdown-wall",
    "button-press", "button-press-wall", "coffee-button", "coffee-pull", "coffee-push", "dial-turn", "disassemble",
    "door-close", "door-lock", "door-open", "door-unlock", "hand-insert", "drawer-close", "drawer-open",
    "faucet-open", "faucet-close", "hammer", "handle-press-side", "handle-press", "handle-pull-side", "handle-pull",
    "lever-pull", "pick-place-wall", "pick-out-of-hole", "pick-place", "plate-slide", "plate-slide-side",
    "plate-slide-back", "plate-slide-back-side", "peg-insert-side", "peg-unplug-side", "soccer", "stick-push",
    "stick-pull", "push", "push-wall", "push-back", "reach", "reach-wall", "shelf-place", "sweep-into", "sweep",
    "window-open", "window-close",
)  # fmt: skip

#: The 16 Meta-World tasks of the paper (v2 in the authors' code, v3 in metaworld 3.x).
METAWORLD_PAPER_TASKS: tuple[str, ...] = (
    "assembly", "basketball", "bin-picking", "box-close", "button-press-topdown", "button-press-topdown-wall",
    "door-close", "door-lock", "door-open", "door-unlock", "drawer-open", "hammer", "lever-pull",
    "peg-insert-side", "shelf-place", "stick-push",
)  # fmt: skip

#: Every valid full name, ``dmc/...``, ``metaworld/...`` then ``dmc-distracting/...``.
ENV_NAMES: tuple[str, ...] = (
    *(f"dmc/{name}" for name in DMC_TASKS),
    *(f"metaworld/{name}" for name in METAWORLD_TASKS),
    *(f"dmc-distracting/{name}" for name in DISTRACTING_TASKS),
)


class TaskName(NamedTuple):
    """A parsed environment name."""

    suite: str
    task: str


def parse_env_name(name: str) -> TaskName:
    """Split ``<suite>/<task>[-v0]`` and check it is a known task; raise ``ValueError`` listing valid names."""
    if not isinstance(name, str):
        raise TypeError(f"env name must be a str like 'dmc/cartpole-swingup', got {type(name).__name__}")
    base = name.removesuffix("-v0")
    if base.startswith("dmc-distracting/") and base.split("/", 1)[1] in DMC_TASKS and base not in ENV_NAMES:
        raise ValueError(
            f"Unknown env name {name!r}: the Distracting Control Suite defines its distractions for the domains "
            f"{', '.join(DISTRACTING_DOMAINS)} only (e.g. 'dmc-distracting/walker-walk')"
        )
    if base not in ENV_NAMES:
        raise ValueError(
            f"Unknown env name {name!r}{did_you_mean(base, ENV_NAMES)}: expected '<suite>/<task>' (optional '-v0' "
            "suffix) with suite 'dmc', 'metaworld' or 'dmc-distracting' (all names: sb3_ef.envs.ENV_NAMES)"
        )
    suite, task = base.split("/", 1)
    return TaskName(suite, task)
