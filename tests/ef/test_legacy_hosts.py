"""Models and checkpoints saved by sb3-ef 0.1.0, converted by ``sb3-ef upgrade`` (sb3_ef.upgrade), load in every
host with the same weights, optimiser states and actions, and training resumes from them as it did under 0.1.0;
``load`` refuses the unconverted files, naming the command.

The files were written under sb3-ef 0.1.0 by tests/drqv2/data/make_drqv2_zips.py and
tests/tdmpc2/data/make_tdmpc2_zips.py (imported here for their environments and observations).
"""

import importlib.util
import io
import shutil
import tempfile
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.save_util import load_from_zip_file

from sb3_ef.common.checkpoints import latest_checkpoint, load_checkpoint
from sb3_ef.drqv2 import DrQv2, DrQv2EF
from sb3_ef.drqv2.policies import DrQv2EFPolicy, DrQv2Policy
from sb3_ef.tdmpc2 import TDMPC2, TDMPC2EF
from sb3_ef.tdmpc2.policies import TDMPC2EFPolicy, TDMPC2Policy
from sb3_ef.upgrade import upgrade

TESTS = Path(__file__).parents[1]
UPGRADED = Path(tempfile.mkdtemp(prefix="sb3_ef_upgraded_"))


def maker(path: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(Path(path).stem, TESTS / path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


DRQV2 = maker("drqv2/data/make_drqv2_zips.py")
TDMPC2_MAKER = maker("tdmpc2/data/make_tdmpc2_zips.py")


class Host:
    """A host's 0.1.0 files and how to act with it as the fixture maker did."""

    def __init__(self, algorithm: type, policy_class: type, data: str, optimizers: tuple[str, ...]):
        self.algorithm, self.policy_class, self.optimizers = algorithm, policy_class, optimizers
        self.stem = TESTS / data / algorithm.__name__.lower()
        self.maker = DRQV2 if algorithm in (DrQv2, DrQv2EF) else TDMPC2_MAKER

    def env(self):
        return self.maker.toy_env(self.maker.SIZES[self.algorithm]) if self.maker is DRQV2 else self.maker.toy_env()

    def actions(self, model) -> np.ndarray:
        if self.maker is DRQV2:
            return model.predict(self.maker.observations(self.maker.SIZES[self.algorithm]), deterministic=True)[0]
        return self.maker.deterministic_actions(model)

    @property
    def legacy_zip(self) -> Path:
        return self.stem.with_name(f"{self.stem.name}_0.1.0.zip")

    @property
    def upgraded_zip(self) -> Path:
        """The 0.1.0 file converted by ``upgrade`` (once per test session)."""
        path = UPGRADED / self.legacy_zip.name
        if not path.is_file():
            assert upgrade(self.legacy_zip, path) is self.algorithm
        return path

    def load(self, **kwargs):
        return self.algorithm.load(self.upgraded_zip, device="cpu", **kwargs)

    def expected(self):
        return np.load(self.stem.with_name(f"{self.stem.name}_0.1.0_expected.npz"))

    def __repr__(self) -> str:
        return self.algorithm.__name__


DRQV2_OPTIMIZERS = ("critic.optimizer", "actor.optimizer")
TDMPC2_OPTIMIZERS = ("policy.optimizer", "policy.pi_optimizer")
HOSTS = [
    Host(DrQv2EF, DrQv2EFPolicy, "drqv2/data", DRQV2_OPTIMIZERS),
    Host(DrQv2, DrQv2Policy, "drqv2/data", DRQV2_OPTIMIZERS),
    Host(TDMPC2EF, TDMPC2EFPolicy, "tdmpc2/data", TDMPC2_OPTIMIZERS),
    Host(TDMPC2, TDMPC2Policy, "tdmpc2/data", TDMPC2_OPTIMIZERS),
]
EF_HOSTS = [host for host in HOSTS if host.algorithm in (DrQv2EF, TDMPC2EF)]


def optimiser_of(model, host: Host, parameter: th.Tensor) -> th.optim.Optimizer:
    for name in host.optimizers:
        optimizer = model
        for part in name.split("."):
            optimizer = getattr(optimizer, part)
        if any(parameter is other for group in optimizer.param_groups for other in group["params"]):
            return optimizer
    raise AssertionError("a trained parameter is in none of the host's optimisers")


@pytest.mark.parametrize("host", HOSTS, ids=repr)
def test_loads_with_the_saved_weights_and_optimiser_states(host):
    model = host.load()
    expected = host.expected()
    assert type(model.policy) is host.policy_class
    assert (getattr(model, "ef", None) is not None) == (host in EF_HOSTS)
    ef_state = model.ef.state_dict() if host in EF_HOSTS else {}
    host_state = {name: value for name, value in model.policy.state_dict().items() if not name.startswith("auxiliary.")}
    loaded = {**{f"host/{n}": v for n, v in host_state.items()}, **{f"ef/{n}": v for n, v in ef_state.items()}}
    assert sorted(loaded) == sorted(key for key in expected if key.startswith(("host/", "ef/")))
    for name, value in loaded.items():
        np.testing.assert_array_equal(value.numpy(), expected[name], err_msg=name)
    # Each parameter's optimiser state (Adam's moments and steps for TD-MPC2; the DrQ-v2 files use stateless SGD).
    saved_names = {key.split("/")[1] for key in expected if key.startswith("state/")}
    assert bool(saved_names) == (host.maker is TDMPC2_MAKER)
    parameters = dict(model.policy.named_parameters())
    for saved_name in saved_names:
        name = f"auxiliary.{saved_name}" if saved_name.startswith("ef.") else saved_name
        state = optimiser_of(model, host, parameters[name]).state[parameters[name]]
        for key in ("exp_avg", "exp_avg_sq", "step"):
            np.testing.assert_array_equal(state[key].numpy(), expected[f"state/{saved_name}/{key}"], err_msg=name)


@pytest.mark.parametrize("host", HOSTS, ids=repr)
def test_random_generators_are_the_saved_ones(host):
    model = host.load()
    saved, _, _ = load_from_zip_file(host.legacy_zip, load_data=True)
    assert th.equal(model._auxiliary_generator.get_state(), saved["_ef_generator"].get_state())
    for name in ("_babbling_rng", "_eval_babbling_rng"):
        assert getattr(model, name).bit_generator.state == saved[name].bit_generator.state


@pytest.mark.parametrize("host", EF_HOSTS, ids=repr)
def test_ef_parameters_get_a_group_of_their_own_with_the_saved_settings(host):
    model = host.load()
    optimizer = model.critic.optimizer if host.algorithm is DrQv2EF else model.policy.optimizer
    *host_groups, auxiliary_group = optimizer.param_groups
    assert [id(p) for p in auxiliary_group["params"]] == [id(p) for p in model.auxiliary.parameters()]
    assert auxiliary_group["lr"] == host_groups[-1]["lr"] == model.lr_schedule(1)
    if host.algorithm is TDMPC2EF:
        assert [group["name"] for group in optimizer.param_groups] == ["encoder", "heads", "auxiliary"]


@pytest.mark.parametrize("host", HOSTS, ids=repr)
def test_acts_as_it_did(host):
    # Float rounding differs across CPUs (vector instructions), not the network the file holds.
    np.testing.assert_allclose(host.actions(host.load()), host.expected()["actions"], rtol=0, atol=1e-5)


@pytest.mark.parametrize("host", HOSTS, ids=repr)
def test_training_continues_and_saves_in_the_current_format(host):
    model = host.load(env=host.env())
    assert model.beta == 1.0 if host in EF_HOSTS else not hasattr(model, "beta")
    assert {"_ef_generator", "beta", "ef_learning_rate"}.isdisjoint(vars(model))
    before = {name: value.clone() for name, value in model.policy.state_dict().items()}
    model.learn(4, reset_num_timesteps=False)
    assert model.num_timesteps == 24
    changed = {name for name, value in model.policy.state_dict().items() if not th.equal(value, before[name])}
    assert any(name.startswith("auxiliary.ef.") for name in changed) == (host in EF_HOSTS)
    file = io.BytesIO()
    model.save(file)
    file.seek(0)
    again = host.algorithm.load(file, device="cpu")
    for name, value in again.policy.state_dict().items():
        assert th.equal(value, model.policy.state_dict()[name]), name


@pytest.mark.parametrize("host", EF_HOSTS, ids=repr)
def test_a_0_1_0_checkpoint_resumes_as_it_did_under_0_1_0(host):
    # The fixture maker resumed the same checkpoint under 0.1.0 for 6 steps (updates, EF steps, babbling over).
    folder = UPGRADED / f"{host.stem.name}_checkpoint"
    shutil.copytree(f"{host.stem}_checkpoint", folder, dirs_exist_ok=True)
    old = latest_checkpoint(folder)
    upgrade(old.model_path, folder / "upgraded.zip")
    (folder / "upgraded.zip").replace(old.model_path)  # the upgraded file takes the checkpoint's place
    model = load_checkpoint(host.algorithm, latest_checkpoint(folder), host.env())
    assert model.replay_buffer.size() == model.num_timesteps == 10
    model.learn(6, reset_num_timesteps=False)
    resumed = np.load(f"{host.stem}_checkpoint_resumed.npz")["actions"]
    # Equal up to float rounding: the tests run torch on one thread, the maker ran on several (other sums' order).
    np.testing.assert_allclose(host.actions(model), resumed, rtol=0, atol=1e-5)


@pytest.mark.parametrize("loader", [DrQv2, DrQv2EF, TDMPC2, TDMPC2EF], ids=repr)
def test_load_refuses_a_0_1_0_file_naming_the_upgrade_command(loader):
    for host in HOSTS:
        with pytest.raises(ValueError, match=r"saved by sb3-ef 0\.1\.0.*`sb3-ef upgrade .*_0\.1\.0\.zip NEW\.zip`"):
            loader.load(host.legacy_zip)


def test_upgrade_refuses_a_file_of_this_version(tmp_path):
    with pytest.raises(ValueError, match=r"DrQv2EF of this version saved it.*nothing to upgrade"):
        upgrade(HOSTS[0].upgraded_zip, tmp_path / "again.zip")
    assert not (tmp_path / "again.zip").exists()


@pytest.mark.parametrize("host", EF_HOSTS, ids=repr)
def test_set_parameters_reads_an_upgraded_file_into_a_model_of_the_same_sizes(host):
    policy, arguments = (
        (DRQV2.EF_POLICY, DRQV2.ARGUMENTS | DRQV2.EF_ARGUMENTS)
        if host.maker is DRQV2
        else (TDMPC2_MAKER.EF_POLICY, TDMPC2_MAKER.ARGUMENTS | TDMPC2_MAKER.EF_ARGUMENTS)
    )
    model = host.algorithm("CnnPolicy", host.env(), policy_kwargs=policy, **arguments)
    model.set_parameters(str(host.upgraded_zip), device="cpu")
    expected = host.expected()
    for name, value in model.ef.state_dict().items():
        np.testing.assert_array_equal(value.numpy(), expected[f"ef/{name}"], err_msg=name)
    np.testing.assert_allclose(host.actions(model), expected["actions"], rtol=0, atol=1e-5)
