"""``sb3-ef upgrade OLD.zip NEW.zip``: a model file of sb3-ef 0.1.0 converted into this version's format."""

from __future__ import annotations

import argparse
import functools
import io
import json
import os
import pathlib
import zipfile
from typing import Any

import torch as th
from stable_baselines3.common.save_util import data_to_json, json_to_data, load_from_zip_file, open_path

from sb3_ef import registry
from sb3_ef.common.files import write_atomically
from sb3_ef.common.saved_models import is_legacy, saved_algorithm, saved_data

#: Attributes 0.1.0 saved under another name.
RENAMED_ATTRIBUTES = {
    "_ef_generator": "_auxiliary_generator",
    "beta": "_beta",
    "ef_learning_rate": "auxiliary_learning_rate",
}
#: EF's attributes, which 0.1.0's plain DrQv2 and TDMPC2 saved as ``None``.
EF_ATTRIBUTES = ("beta", "ef_horizon")
#: What 0.1.0's DrQ-v2 and TD-MPC2 added to the saved ``policy_kwargs`` from the algorithm's arguments.
ALGORITHM_POLICY_KWARGS = ("ef_horizon", "horizon", "gamma")
#: EF's policy arguments, which 0.1.0's plain policies accepted and ignored.
EF_POLICY_KWARGS = ("agent_dim", "ef_kwargs")
#: The name of EF's parameter group in 0.1.0's TD-MPC2 world-model optimiser.
EF_GROUP = "ef"


def upgraded_file(
    path: str | pathlib.Path | io.BufferedIOBase,
    algorithm: type,
    with_ef: bool,
    custom_objects: dict[str, Any] | None = None,
) -> str | pathlib.Path | io.BufferedIOBase:
    """``path`` itself, or for a 0.1.0 file an in-memory copy with the data ``algorithm`` saves."""
    file = open_path(path, "r", verbose=0, suffix="zip")
    position = file.tell()
    try:
        with zipfile.ZipFile(file) as archive:
            entries = {name: archive.read(name) for name in archive.namelist()}
        data = json.loads(entries["data"])
    except (zipfile.BadZipFile, KeyError, ValueError):
        return path  # SB3's load reports what is wrong with the file
    finally:
        if isinstance(path, io.BufferedIOBase):
            file.seek(position)
        else:
            file.close()
    if "algorithm" in data:
        return path
    saved_with_ef = data.get("ef_horizon") is not None
    if saved_with_ef != with_ef:
        raise ValueError(
            f"Cannot load {path} as {algorithm.__name__}: sb3-ef 0.1.0 saved it "
            f"{'with' if saved_with_ef else 'without'} Ego-Foresight, load it with the "
            f"{'Ego-Foresight' if saved_with_ef else 'plain'} variant of the algorithm"
        )
    entries["data"] = json.dumps(_upgraded_data(data, algorithm, with_ef, custom_objects or {}), indent=4).encode()
    upgraded = io.BytesIO()
    with zipfile.ZipFile(upgraded, "w") as archive:
        for name, content in entries.items():
            archive.writestr(name, content)
    upgraded.seek(0)
    return upgraded


def _upgraded_data(
    data: dict[str, Any], algorithm: type, with_ef: bool, custom_objects: dict[str, Any]
) -> dict[str, Any]:
    """The JSON data of a 0.1.0 file as ``algorithm`` saves it (entries it does not touch stay as serialised)."""
    if not with_ef:
        data = {key: value for key, value in data.items() if key not in EF_ATTRIBUTES}
    data = {RENAMED_ATTRIBUTES.get(key, key): value for key, value in data.items()}
    saved = {key: data[key] for key in ("policy_class", "policy_kwargs") if key in data}
    values = json_to_data(json.dumps(saved), custom_objects)  # SB3 deserialises them: classes are pickled
    policy_class = values.get("policy_class")
    if isinstance(policy_class, type):  # the EF variant's policy, a subclass of the plain one 0.1.0 saved
        aliases = getattr(algorithm, "policy_aliases", {}).values()
        subclasses = [alias for alias in aliases if alias is not policy_class and issubclass(alias, policy_class)]
        values["policy_class"] = subclasses[0] if subclasses else policy_class
    if isinstance(values.get("policy_kwargs"), dict):
        dropped = ALGORITHM_POLICY_KWARGS if with_ef else ALGORITHM_POLICY_KWARGS + EF_POLICY_KWARGS
        values["policy_kwargs"] = {key: value for key, value in values["policy_kwargs"].items() if key not in dropped}
    data.update(json.loads(data_to_json(values)))
    data["algorithm"] = algorithm.__name__
    return data


def upgraded_parameters(
    load_path_or_dict: str | pathlib.Path | io.BufferedIOBase | dict[str, Any], model: Any, device: th.device | str
) -> dict[str, Any]:
    """The state dicts for SB3's ``set_parameters``, a 0.1.0 EF model's moved to where ``model`` keeps them."""
    if isinstance(load_path_or_dict, dict):
        params = load_path_or_dict
    else:
        _, params, _ = load_from_zip_file(load_path_or_dict, device=device, load_data=False)
    policy = params.get("policy", {})
    if not any(name.startswith("ef.") for name in policy) and "ef_optimizer" not in params:
        return params
    state_dicts, _ = model._get_torch_save_params()
    upgraded = {key: value for key, value in params.items() if key not in ("policy", "ef_optimizer")}
    host = {name: value for name, value in policy.items() if not name.startswith("ef.")}
    ef = {name: value for name, value in policy.items() if name.startswith("ef.")}
    if "auxiliary_module" in state_dicts:  # the auxiliary module beside the policy (the SB3 hosts)
        upgraded.update(policy=host, auxiliary_module=ef)
    else:  # the auxiliary module on the policy, holding the EF module as its ``ef``
        upgraded["policy"] = {**host, **{f"auxiliary.{name}": value for name, value in ef.items()}}
    if "ef_optimizer" in params:
        upgraded["auxiliary_optimizer"] = params["ef_optimizer"]
    for name in state_dicts:
        optimizer = functools.reduce(lambda value, part: getattr(value, part, None), name.split("."), model)
        if isinstance(optimizer, th.optim.Optimizer) and name in upgraded:
            upgraded[name] = _regrouped(upgraded[name], optimizer, name)
    return upgraded


def _regrouped(state: dict[str, Any], optimizer: th.optim.Optimizer, name: str) -> dict[str, Any]:
    """A 0.1.0 optimiser state split or renamed into ``optimizer``'s parameter groups."""
    saved_groups, groups = state["param_groups"], optimizer.param_groups
    saved_sizes = [len(group["params"]) for group in saved_groups]
    sizes = [len(group["params"]) for group in groups]
    if saved_sizes == sizes:
        regrouped = [
            {**saved, "name": group["name"]} if "name" in group and saved.get("name") == EF_GROUP else saved
            for saved, group in zip(saved_groups, groups, strict=True)
        ]
    elif len(saved_groups) == 1 and sum(sizes) == saved_sizes[0]:
        indices, start, regrouped = saved_groups[0]["params"], 0, []
        for size in sizes:
            regrouped.append({**saved_groups[0], "params": indices[start : start + size]})
            start += size
    else:
        raise ValueError(
            f"The saved {name} has parameter groups of {saved_sizes} parameters, which do not match the model's "
            f"{sizes}: the file was saved with other network sizes"
        )
    return {**state, "param_groups": regrouped}


def legacy_algorithm(data: dict[str, Any]) -> type:
    """The registry's algorithm whose 0.1.0 files hold ``data``'s policy class, with EF or not as ``data``."""
    with_ef = data.get("ef_horizon") is not None
    module = (data.get("policy_class") or {}).get("__module__")
    candidates = [item for item in registry.ALGORITHMS.values() if item.legacy_policy_module == module]
    if not candidates:
        modules = sorted({item.legacy_policy_module or "" for item in registry.ALGORITHMS.values()} - {""})
        raise ValueError(f"A file of sb3-ef 0.1.0 holds one of the policies of {modules}, got {module!r}")
    matching = [item for item in candidates if item.ef == with_ef] if len(candidates) > 1 else candidates
    return matching[0].algorithm_class


def upgrade(source: str | os.PathLike, destination: str | os.PathLike, device: str = "cpu") -> type:
    """Convert ``source``, saved by sb3-ef 0.1.0, into ``destination`` (atomically); return the loading class."""
    data = saved_data(source)
    if data is None:
        raise ValueError(f"{source} is not a saved model: expected a zip archive written by save()")
    if not is_legacy(data):
        saved = saved_algorithm(data)
        who = f"{saved} of this version saved it" if saved else "no sb3-ef algorithm saved it"
        raise ValueError(f"{source} is not a file of sb3-ef 0.1.0 ({who}): nothing to upgrade")
    if os.path.abspath(source) == os.path.abspath(destination):
        raise ValueError(f"The upgraded file must go to another path than {source} (the original is kept)")
    folder = os.path.dirname(os.path.abspath(destination))
    if not os.path.isdir(folder):
        raise FileNotFoundError(f"No folder {folder} to write {destination} into: create it first")
    algorithm = legacy_algorithm(data)
    file = upgraded_file(pathlib.Path(source), algorithm, algorithm.__name__.endswith("EF"))

    class Upgrading(algorithm):  # type: ignore[misc, valid-type]
        """The algorithm, reading the 0.1.0 weights and optimiser states into this version's places."""

        def set_parameters(self, load_path_or_dict: Any, exact_match: bool = True, device: Any = "auto") -> None:
            params = upgraded_parameters(load_path_or_dict, self, device)
            super().set_parameters(params, exact_match, device)

    Upgrading.__name__ = Upgrading.__qualname__ = algorithm.__name__  # the name the upgraded data records
    model = Upgrading.load(file, device=device)
    model.__class__ = algorithm
    write_atomically(destination, model.save)
    return algorithm


def main(argv: list[str] | None = None) -> int:
    """``sb3-ef upgrade OLD.zip NEW.zip``: convert, refusing to write over an existing file."""
    parser = argparse.ArgumentParser(
        prog="sb3-ef upgrade", description="Convert a model file saved by sb3-ef 0.1.0 into this version's format."
    )
    parser.add_argument("source", help="the model zip saved by sb3-ef 0.1.0 (kept unchanged)")
    parser.add_argument("destination", help="where to write the converted model zip (must not exist)")
    args = parser.parse_args(argv)
    if not os.path.isfile(args.source):
        parser.error(f"no model file at {args.source}")
    if os.path.exists(args.destination):
        parser.error(f"{args.destination} exists: name a new file (nothing is written over)")
    algorithm = upgrade(args.source, args.destination)
    print(f"Wrote {args.destination}: load it with {algorithm.__name__}.load")
    return 0
