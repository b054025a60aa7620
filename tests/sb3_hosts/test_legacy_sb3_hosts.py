"""A SAC-EF model saved by sb3-ef 0.1.0 (written by data/make_sacef_zip.py; weights and actions are checked in
test_contract_sb3_hosts.py), converted by ``sb3-ef upgrade``, keeps its attributes and EF optimiser under this
version's names."""

from pathlib import Path

import torch as th
from stable_baselines3.common.save_util import load_from_zip_file

from sb3_ef import SACEF
from sb3_ef.upgrade import upgrade

ZIP = Path(__file__).parent / "data" / "sacef_0.1.0.zip"


def test_attributes_and_ef_optimiser_come_back_under_their_names(tmp_path):
    assert upgrade(ZIP, tmp_path / "sacef.zip") is SACEF
    model = SACEF.load(tmp_path / "sacef.zip", device="cpu")
    saved, params, _ = load_from_zip_file(ZIP, device="cpu")
    assert {"_ef_generator", "beta", "ef_learning_rate", "ef_optimizer"}.isdisjoint(vars(model))
    assert model.auxiliary_learning_rate == saved["ef_learning_rate"]
    assert model.beta == saved["beta"]
    assert th.equal(model._auxiliary_generator.get_state(), saved["_ef_generator"].get_state())
    # The EF optimiser's parameters are EF's, then the encoder's, as in 0.1.0: its state carries over index by index.
    loaded = model.auxiliary_optimizer.state_dict()
    assert loaded["param_groups"][0]["params"] == params["ef_optimizer"]["param_groups"][0]["params"]
    assert loaded["state"].keys() == params["ef_optimizer"]["state"].keys() != set()
    for index, state in params["ef_optimizer"]["state"].items():
        for key, value in state.items():
            assert th.equal(loaded["state"][index][key], value), (index, key)
    parameters = [*model.ef.parameters(), *model.critic.features_extractor.parameters()]
    assert [id(p) for p in model.auxiliary_optimizer.param_groups[0]["params"]] == [id(p) for p in parameters]
