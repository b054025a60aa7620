"""SB3's save / load tests (stable_baselines3 tests/test_save_load.py, and test_run.py's train, save, load with new
arguments and train again) adapted to DreamerV3: parameters, set_env, the options of load and save, paths and file
objects, files of other classes. docs/dreamerv3.md lists each difference from SB3 these tests hold."""

from __future__ import annotations

import io
from collections import OrderedDict
from copy import deepcopy

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.vec_env import DummyVecEnv

from tests.dreamerv3.dreamerv3_tiny import toy

pytest.importorskip("sheeprl")

from sb3_ef.dreamerv3 import DreamerV3
from sb3_ef.drqv2 import DrQv2EF


@pytest.fixture
def loaded(trained, tmp_path) -> DreamerV3:
    """A copy of the trained model (saved, loaded on a new toy env)."""
    trained.model.save(tmp_path / "trained.zip")
    return DreamerV3.load(tmp_path / "trained.zip", env=toy(), device="cpu", work_dir=tmp_path / "loaded")


def assert_parameters_equal(expected: dict, given: dict) -> None:
    for name in expected:
        if "optim" not in name:  # SB3's test does not compare optimisers either
            for key, value in expected[name].items():
                assert th.allclose(value.cpu(), given[name][key].cpu()), (name, key)


def test_save_load(loaded, tmp_path):
    """SB3's ``test_save_load``: get_parameters / set_parameters and their errors, then save and load on each device
    with the same parameters and actions, and learn on from them."""
    model = loaded
    observations = np.stack([toy().reset(seed=seed)[0] for seed in range(10)])
    original_params = deepcopy(model.get_parameters())

    invalid_object_params = deepcopy(original_params)
    invalid_object_params["I_should_not_be_a_valid_object"] = "and_I_am_an_invalid_tensor"
    for exact_match in (True, False):
        with pytest.raises(ValueError, match="not parameters of DreamerV3"):
            model.set_parameters(invalid_object_params, exact_match=exact_match)
    missing_object_params = dict(list(original_params.items())[:-1])
    with pytest.raises(ValueError, match="missing"):
        model.set_parameters(missing_object_params, exact_match=True)
    missing_state_dict_tensor_params = {name: dict(list(value.items())[:-1]) for name, value in original_params.items()}
    with pytest.raises(RuntimeError, match="missing"):
        model.set_parameters(missing_state_dict_tensor_params, exact_match=True)

    random_params = {}  # the last entry of each state dict left out, the optimisers kept
    for name, params in original_params.items():
        items = list(params.items())[:-1]
        random_params[name] = params if "optim" in name else OrderedDict((key, th.rand_like(v)) for key, v in items)
    model.set_parameters(random_params, exact_match=False)
    new_params = model.get_parameters()
    for name in original_params:
        if "optim" not in name:
            last_key = list(original_params[name])[-1]
            for key in original_params[name]:
                unchanged = th.allclose(original_params[name][key], new_params[name][key])
                assert unchanged == (key == last_key), f"{name}.{key}"

    params = deepcopy(new_params)
    selected_actions, _ = model.predict(observations, deterministic=True)
    model.save(tmp_path / "test_save.zip")
    for device in ["auto", "cpu", "cuda"]:  # "cuda" falls back to the CPU where there is none, with a warning
        model = DreamerV3.load(str(tmp_path / "test_save.zip"), env=toy(), device=device, work_dir=tmp_path / device)
        assert_parameters_equal(params, model.get_parameters())
        new_selected_actions, _ = model.predict(observations, deterministic=True)
        assert np.allclose(selected_actions, new_selected_actions, 1e-4)
    # learn goes on from the parameters set (its first 8 steps fill a new replay buffer: no update yet)
    model.learn(total_timesteps=4, reset_num_timesteps=False)
    assert model.num_timesteps == 41
    assert_parameters_equal(params, model.get_parameters())


def test_set_env(loaded, tmp_path):
    """SB3's ``test_set_env``: another env (a VecEnv of one or a gymnasium env) for the next learn, a loaded model
    learning twice, the step count kept through save and load."""
    model = loaded
    env2, env3, env4 = DummyVecEnv([toy]), toy(), DummyVecEnv([toy, toy])
    model.set_env(env2, force_reset=True)
    model.learn(total_timesteps=4, reset_num_timesteps=False)
    assert model.num_timesteps == 41
    model.set_env(env3)
    model.learn(total_timesteps=4, reset_num_timesteps=False)
    assert model.num_timesteps == 45
    with pytest.raises(ValueError, match=r"one gymnasium env or a DummyVecEnv of one .* of 2 envs"):
        model.set_env(env4)
    with pytest.raises(ValueError, match="force_reset=False"):
        model.set_env(model.get_env(), force_reset=False)
    with pytest.raises(ValueError, match="trained on 16x16 frames, the env gives 32x32"):
        model.set_env(toy(size=32))
    model.set_env(model.get_env())

    model.save(tmp_path / "test_save.zip")
    with pytest.raises(ValueError, match="force_reset=False"):
        DreamerV3.load(tmp_path / "test_save.zip", env=model.get_env(), force_reset=False)
    model = DreamerV3.load(tmp_path / "test_save.zip", env=env3, force_reset=True, work_dir=tmp_path / "again")
    model.learn(total_timesteps=4, reset_num_timesteps=False)
    assert model.num_timesteps == 49


def test_load_takes_new_values_of_the_settings_a_loaded_model_uses(loaded, tmp_path, capsys):
    """SB3's ``test_exclude_include_saved_params`` and test_run.py's load with new arguments: ``custom_objects``
    and keyword arguments set ``learning_starts``, ``seed`` and ``verbose``; the others are the saved run's."""
    loaded.save(tmp_path / "test_save")
    with pytest.raises(TypeError, match="exclude"):
        loaded.save(tmp_path / "test_save", exclude=["verbose"])
    model = DreamerV3.load(
        str(tmp_path / "test_save.zip"), custom_objects={"verbose": 2}, print_system_info=True, device="cpu"
    )
    assert model.verbose == 2
    printed = capsys.readouterr().out
    assert "== CURRENT SYSTEM INFO ==" in printed and "== SAVED MODEL SYSTEM INFO ==" in printed
    assert printed.count("- PyTorch: ") == 2
    with pytest.raises(ValueError, match=r"\['learning_rate'\] cannot be changed .* these can: \['learning_starts'"):
        DreamerV3.load(tmp_path / "test_save.zip", custom_objects={"learning_rate": 2e-5})

    before = model.get_parameters()
    model = DreamerV3.load(tmp_path / "test_save.zip", env=toy(), learning_starts=4, seed=3, work_dir=tmp_path / "w")
    assert (model.settings["learning_starts"], model.seed) == (4, 3)
    model.learn(total_timesteps=4, reset_num_timesteps=False)  # trains at its 4th step, after its new warm-up
    changed = model.get_parameters()["actor"]
    assert any(not th.equal(value, before["actor"][key]) for key, value in changed.items())


@pytest.mark.parametrize("name", ["model", "model.zip"])
def test_save_adds_zip_and_load_takes_the_path_either_way(trained, tmp_path, name):
    model = trained.model
    model.save(tmp_path / name)
    assert sorted(path.name for path in tmp_path.iterdir()) == ["model.zip"]
    observation, _ = toy().reset(seed=4)
    expected, _ = model.predict(observation, deterministic=True)
    for given in ("model", "model.zip"):
        loaded = DreamerV3.load(tmp_path / given, device="cpu", work_dir=tmp_path / "work")
        assert loaded.num_timesteps == 37 and loaded.get_env() is None
        np.testing.assert_array_equal(loaded.predict(observation, deterministic=True)[0], expected)


def test_save_and_load_take_file_objects(trained, tmp_path):
    file = io.BytesIO()
    trained.model.save(file)
    file.seek(0)
    assert_parameters_equal(trained.model.get_parameters(), DreamerV3.load(file, device="cpu").get_parameters())


def test_other_classes_name_the_class_in_the_file(trained, tmp_path):
    trained.model.save(tmp_path / "dreamer.zip")
    with pytest.raises(ValueError, match=r"saved by DreamerV3, use DreamerV3\.load"):
        DrQv2EF.load(tmp_path / "dreamer.zip")
    DrQv2EF("CnnPolicy", toy(size=32), buffer_size=100).save(tmp_path / "drqv2.zip")
    with pytest.raises(ValueError, match=r"saved by DrQv2EF, use DrQv2EF\.load"):
        DreamerV3.load(tmp_path / "drqv2.zip")
