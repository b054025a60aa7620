"""Task names: in sync with the installed suites, parsed with an optional -v0, unknown names rejected."""

import pytest
from dm_control import suite
from metaworld.env_dict import ALL_V3_ENVIRONMENTS

from sb3_ef.envs.tasks import (
    DISTRACTING_DOMAINS,
    DISTRACTING_TASKS,
    DMC_PAPER_TASKS,
    DMC_TASKS,
    ENV_NAMES,
    METAWORLD_PAPER_TASKS,
    METAWORLD_TASKS,
    TaskName,
    parse_env_name,
)


def test_names_cover_the_installed_suites():
    assert sorted(DMC_TASKS.values()) == sorted(suite.ALL_TASKS)
    assert sorted(f"{task}-v3" for task in METAWORLD_TASKS) == sorted(ALL_V3_ENVIRONMENTS)
    assert set(DMC_PAPER_TASKS) <= set(DMC_TASKS) and len(DMC_PAPER_TASKS) == 12
    assert set(METAWORLD_PAPER_TASKS) <= set(METAWORLD_TASKS) and len(METAWORLD_PAPER_TASKS) == 16
    assert len(ENV_NAMES) == len(set(ENV_NAMES)) == len(DMC_TASKS) + len(METAWORLD_TASKS) + len(DISTRACTING_TASKS)


def test_distracting_control_names_are_the_dmc_tasks_of_its_six_domains():
    domains = {domain for domain, _ in DISTRACTING_TASKS.values()}
    assert domains == set(DISTRACTING_DOMAINS) and len(domains) == 6
    assert {name: pair for name, pair in DMC_TASKS.items() if pair[0] in domains} == DISTRACTING_TASKS
    assert {"cartpole-balance", "walker-walk", "ball-in-cup-catch", "reacher-easy"} <= set(DISTRACTING_TASKS)


@pytest.mark.parametrize(
    "name, parsed",
    [
        ("dmc/cartpole-swingup-sparse", TaskName("dmc", "cartpole-swingup-sparse")),
        ("dmc/ball-in-cup-catch-v0", TaskName("dmc", "ball-in-cup-catch")),
        ("metaworld/button-press-topdown-wall", TaskName("metaworld", "button-press-topdown-wall")),
        ("metaworld/hammer-v0", TaskName("metaworld", "hammer")),
        ("dmc-distracting/cartpole-balance-v0", TaskName("dmc-distracting", "cartpole-balance")),
    ],
)
def test_parse_env_name(name, parsed):
    assert parse_env_name(name) == parsed


def test_dmc_names_map_to_suite_domain_and_task():
    assert DMC_TASKS["cartpole-swingup-sparse"] == ("cartpole", "swingup_sparse")
    assert DMC_TASKS["ball-in-cup-catch"] == ("ball_in_cup", "catch")


@pytest.mark.parametrize(
    ("name", "closest"),
    [
        ("dmc/cartpole", "dmc/cartpole-swingup"),
        ("dmc/cartpole_swingup", "dmc/cartpole-swingup"),
        ("gym/reacher-easy", "dmc/reacher-easy"),
        ("metaworld/hammer-v2", "metaworld/hammer"),
    ],
)
def test_unknown_names_suggest_the_closest_valid_ones(name, closest):
    with pytest.raises(ValueError, match=f"Unknown env name '{name}' \\(did you mean '{closest}'.*ENV_NAMES"):
        parse_env_name(name)


def test_non_string_name_is_a_type_error():
    with pytest.raises(TypeError, match="got int"):
        parse_env_name(3)
