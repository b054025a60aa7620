"""Constructor arguments refused at once, naming sb3-ef's class, the argument, the value and what is expected
(the cases of ``tests/test_bad_inputs.py`` that reach SB3's classes or a file ``load`` cannot read)."""

from __future__ import annotations

import pytest
import torch as th

from sb3_ef import CURL, SACEF, SEAR, TD3EF, DrQv2EF
from sb3_ef.common.validation import check_algorithm_arguments, check_keyword_arguments
from sb3_ef.offline.encoders import DCGANUNetEncoder
from tests.test_bad_inputs import SAC_EF, SAC_POLICY, Case, drqv2_ef, toy_env

STD = r"must be a number >= 0, a string 'linear\(initial, final, duration\)' of numbers >= 0 or a callable of the step"
ENT_COEF = r"ent_coef must be a number >= 0 \(a fixed entropy coefficient\), "
ENT_COEF += r"'auto' or 'auto_<initial value > 0>' \(learned\)"


def torch_file(tmp_path, name: str) -> str:
    path = tmp_path / name
    th.save({"model": {}, "config": {}}, path)
    return str(path)


CASES = [
    Case("SACEF MlpPolicy on pixels", lambda: SACEF("MlpPolicy", toy_env(), **SAC_EF), ValueError,
         r"SACEF: policy 'MlpPolicy' would flatten the env's \(9, 32, 32\) frames .* expected 'CnnPolicy'"),
    Case("DrQv2EF exploration_std -1", lambda: drqv2_ef(exploration_std=-1), ValueError,
         rf"DrQv2EF: exploration_std is a standard deviation: it {STD}, got -1$"),
    Case("SEAR exploration_std -1", lambda: SEAR("CnnPolicy", toy_env(), exploration_std=-1), ValueError,
         r"SEAR: exploration_std is a standard deviation"),
    Case("schedule from below zero", lambda: drqv2_ef(exploration_std="linear(-1, 0.1, 1000)"), ValueError,
         r"exploration_std is a standard deviation: .* got 'linear\(-1, 0.1, 1000\)' \(from -1 to 0.1\)"),
    Case("schedule not a schedule", lambda: drqv2_ef(exploration_std="lin(1, 0.1)"), ValueError,
         rf"DrQv2EF: exploration_std {STD}.*, got str 'lin\(1, 0.1\)'"),
    Case("CURL ent_coef -0.1", lambda: CURL("CnnPolicy", toy_env(), ent_coef=-0.1), ValueError,
         rf"CURL: {ENT_COEF}, got -0.1"),
    Case("CURL ent_coef 'bogus'", lambda: CURL("CnnPolicy", toy_env(), ent_coef="bogus"), ValueError,
         rf"CURL: {ENT_COEF}, got str 'bogus'"),
    Case("CURL ent_coef 'auto_-1'", lambda: CURL("CnnPolicy", toy_env(), ent_coef="auto_-1"), ValueError, ENT_COEF),
    Case("CURL beta", lambda: CURL("CnnPolicy", toy_env(), beta=1), TypeError,
         r"^CURL takes no argument beta=1 \(an argument of Ego-Foresight's classes DrQv2EF, .*\); see help\(CURL\)"),
    Case("CURL agent_dim", lambda: CURL("CnnPolicy", toy_env(), agent_dim=8), TypeError,
         r"^CURL takes no argument agent_dim=8 \(an argument of Ego-Foresight's"),
    Case("CURL argument typo", lambda: CURL("CnnPolicy", toy_env(), batch_sise=8), TypeError,
         r"CURL takes no argument batch_sise=8 \(did you mean 'batch_size'\?\)"),
    Case("SACEF features_dim in policy_kwargs",
         lambda: SACEF("CnnPolicy", toy_env(), policy_kwargs={"features_dim": 64}, **SAC_EF), ValueError,
         r"SACEF: policy_kwargs holds features_dim=64, which CnnPolicy does not take: it is an argument of the "
         r"features extractor NatureCNN: policy_kwargs=dict\(features_extractor_kwargs=dict\(features_dim=64\)\)"),
    Case("TD3EF features_dim in policy_kwargs",
         lambda: TD3EF("CnnPolicy", toy_env(), policy_kwargs={**SAC_POLICY, "features_dim": 64}, **SAC_EF), ValueError,
         r"TD3EF: .* it is an argument of the features extractor DrQv2Encoder: policy_kwargs=dict\(features_extr"),
    Case("CURL features_dim in policy_kwargs",
         lambda: CURL("CnnPolicy", toy_env(), policy_kwargs={"features_dim": 64}), ValueError,
         r"CURL: policy_kwargs holds features_dim=64, which CURLPolicy does not take: it is CURL's own argument: "
         r"CURL\(\.\.\., features_dim=64\)"),
    Case("SACEF policy_kwargs typo", lambda: SACEF("CnnPolicy", toy_env(), policy_kwargs={"net_arc": [8]}, **SAC_EF),
         ValueError, r"SACEF: policy_kwargs holds net_arc=\[8\], which CnnPolicy does not take: expected one of .*"
         r"\(did you mean 'net_arch'\?\)"),
    Case("DrQv2EF.load of pretrain's model.pt", lambda tmp_path: DrQv2EF.load(torch_file(tmp_path, "model.pt")),
         ValueError, r"model.pt is a PyTorch file \(torch.save\), not a model zip written by save\(\): a `sb3-ef "
         r"pretrain` output .* is read with sb3_ef.offline.load_pretrained, .*load_ef\(model, path\)"),
    Case("SACEF.load of pretrain's checkpoint.pt",
         lambda tmp_path: SACEF.load(torch_file(tmp_path, "checkpoint.pt")), ValueError,
         r"checkpoint.pt is a PyTorch file"),
    Case("encoder kwargs typo",
         lambda: check_keyword_arguments("the dcgan-unet encoder (--encoder-kwargs)", DCGANUNetEncoder, {"widht": 64},
                                         set_by_caller=("in_channels",)), ValueError,
         r"^unknown key 'widht' for the dcgan-unet encoder \(--encoder-kwargs\) \(did you mean 'width'\?\); "
         r"expected one of features_dim, skip_block, width$"),
]  # fmt: skip


@pytest.mark.parametrize("case", CASES, ids=[case.name for case in CASES])
def test_bad_argument_is_refused_at_construction(case, tmp_path):
    run = (lambda: case.run(tmp_path)) if case.run.__code__.co_argcount else case.run
    with pytest.raises(case.error, match=case.message):
        run()


@pytest.mark.parametrize(
    "arguments",
    [
        {"exploration_std": 0.0},
        {"exploration_std": "linear(1.0, 0.1, 500000)"},
        {"exploration_std": lambda step: 0.2},
        {"ent_coef": "auto"},
        {"ent_coef": "auto_0.1"},
        {"ent_coef": 0},
    ],
)
def test_valid_values_pass(arguments):
    check_algorithm_arguments(DrQv2EF if "exploration_std" in arguments else CURL, arguments)
