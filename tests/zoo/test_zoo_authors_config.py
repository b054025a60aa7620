"""zoo_configs/drqv2_ef_metaworld_authors.yml: the EF authors' Meta-World protocol as one zoo entry."""

from __future__ import annotations

import inspect
from pathlib import Path

import pytest

from sb3_ef.drqv2 import DrQv2EF
from sb3_ef.envs.meta_world import AUTHORS_DISCOUNT, authors_gamma
from sb3_ef.zoo.config import default_config_path, load_config, validate_config

AUTHORS_CONFIG = Path(__file__).resolve().parents[2] / "zoo_configs" / "drqv2_ef_metaworld_authors.yml"
PROTOCOL_KEYS = {"gamma", "env_kwargs", "babbling_mode", "babbling_in_eval"}


@pytest.mark.skipif(
    "babbling_in_eval" not in inspect.signature(DrQv2EF.__init__).parameters,
    reason="the entry uses the host argument babbling_in_eval (EF integration issue)",
)
def test_authors_entry_is_the_paper_entry_plus_their_protocol():
    config = load_config(AUTHORS_CONFIG)
    validate_config("drqv2_ef", DrQv2EF, config, source=AUTHORS_CONFIG.name)
    (env_id, entry), *others = config.items()
    assert env_id == "metaworld/hammer-v0" and not others
    paper = load_config(default_config_path("drqv2_ef"))[env_id]
    assert {key: value for key, value in entry.items() if key not in PROTOCOL_KEYS} == {
        key: value for key, value in paper.items() if key not in PROTOCOL_KEYS
    }
    assert entry["env_kwargs"] == {"repeat_discount": AUTHORS_DISCOUNT}
    assert entry["gamma"] == pytest.approx(authors_gamma(), abs=1e-12)
    assert (entry["babbling_mode"], entry["babbling_in_eval"]) == ("clamped_uniform", True)
