"""Latent Ego-Foresight (``ef_kwargs=dict(target="latent")``) on every EF host: it trains, its gradient reaches only
the online encoder, the rollout and the latent head, its target encoder follows by momentum outside every optimiser,
and a saved model loads exactly and takes the same next update."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.logger import configure
from stable_baselines3.common.utils import polyak_update
from torch._dynamo.utils import counters

from sb3_ef import SACEF, TD3EF, TDMPC2EF, TQCEF, DrQv2EF
from sb3_ef.analysis.saliency import decoder_saliency
from sb3_ef.drqv2.policies import DrQv2Encoder
from sb3_ef.ef.latent import MomentumTarget
from sb3_ef.ef.probe import fit_probe
from sb3_ef.envs.toy import ToyAgentEnv

HOSTS = [DrQv2EF, TDMPC2EF, SACEF, TD3EF, TQCEF]
SB3_HOSTS = (SACEF, TD3EF, TQCEF)
LATENT = {"target": "latent", "rollout_hidden_dims": (16,), "decoder_channels": 4, "projection_dim": 8,
          "head_hidden_dim": 16}  # fmt: skip
COMMON = {"buffer_size": 200, "learning_starts": 12, "batch_size": 6, "seed": 0, "ef_horizon": 3}


def env_for(algorithm) -> ToyAgentEnv:
    return ToyAgentEnv(size=64 if algorithm is TDMPC2EF else 32, max_episode_steps=15)


def make(algorithm, **kwargs):
    ef = dict(LATENT)
    if algorithm is DrQv2EF:
        policy = {"net_arch": [8], "trunk_dim": 8, "features_dim": 16, "agent_dim": 4, "ef_kwargs": ef}
        extra = {"policy_kwargs": policy, "babbling_steps": 0}
    elif algorithm is TDMPC2EF:
        planner = {"iterations": 1, "num_samples": 8, "num_elites": 2, "num_pi_trajs": 1}
        policy = {
            "num_channels": 4,
            "mlp_dim": 16,
            "num_q": 2,
            "agent_dim": 16,
            "ef_kwargs": ef,
            "planner_kwargs": planner,
        }
        extra = {"policy_kwargs": policy, "babbling_steps": 0, "seed_burst": False}
    else:
        policy = {"net_arch": [8], "normalize_images": False, "features_extractor_class": DrQv2Encoder,
                  "features_extractor_kwargs": {"features_dim": 16}}  # fmt: skip
        extra = {"policy_kwargs": policy, "agent_dim": 4, "ef_kwargs": ef}
    return algorithm("CnnPolicy", env_for(algorithm), **COMMON, **extra, **kwargs)


def online_encoder(model) -> th.nn.Module:
    """The module the host passes to ``after_update`` (the one latent EF's target copies)."""
    if isinstance(model, DrQv2EF):
        return model.policy.encoder
    if isinstance(model, TDMPC2EF):
        return model.world_model.encoder
    return model.critic.features_extractor


def trained_parameters(model) -> dict[str, th.Tensor]:
    """Every parameter of the model (host networks and auxiliary module), by name."""
    named = dict(model.policy.named_parameters())
    if isinstance(model, SB3_HOSTS):
        named.update({f"auxiliary.{n}": p for n, p in model.auxiliary.named_parameters()})
    return named


def optimisers(model) -> list[th.optim.Optimizer]:
    found = [value for value in vars(model).values() if isinstance(value, th.optim.Optimizer)]
    for module in model.policy.modules():
        found += [value for value in vars(module).values() if isinstance(value, th.optim.Optimizer)]
    return found


def state(model) -> dict[str, th.Tensor]:
    """A copy of the model's weights and of the auxiliary module's state (its target encoder included), by name."""
    tensors = {**model.policy.state_dict(), **{f"aux.{n}": t for n, t in model.auxiliary.state_dict().items()}}
    return {name: tensor.clone() for name, tensor in tensors.items()}


@pytest.mark.parametrize("algorithm", HOSTS)
def test_latent_ef_trains_and_its_target_encoder_follows_by_momentum(algorithm):
    model = make(algorithm)
    target = model.auxiliary.target_encoder
    assert isinstance(target, MomentumTarget) and list(target.parameters()) == []
    observations = th.as_tensor(np.stack([model.observation_space.sample() for _ in range(4)]))
    with th.no_grad():  # the copy starts as the online encoder, fed as the host feeds it
        assert th.equal(target.features(observations), model.encode(observations))
    initial = {n: b.clone() for n, b in target.encoder.named_buffers()}
    model.learn(20)
    assert model._n_updates > 0 and np.isfinite(model.logger.name_to_value["train/ef_loss"])
    # One more update by hand: the target moves by tau towards the online encoder, and by nothing else.
    encoder = online_encoder(model)
    before = [b.clone() for b in target.encoder.buffers()]
    online_before = [p.detach().clone() for p in encoder.parameters()]
    expected = [b.clone() for b in before]
    polyak_update(list(encoder.parameters()), expected, target.tau)
    model.auxiliary.after_update(encoder)
    for got, want, start in zip(target.encoder.buffers(), expected, before, strict=True):
        assert th.equal(got, want) and not th.equal(got, start)
    assert all(th.equal(p, q) for p, q in zip(encoder.parameters(), online_before, strict=True))
    assert any(not th.equal(initial[n], b) for n, b in target.encoder.named_buffers())


@pytest.mark.filterwarnings("ignore:learning_starts=100 is not below")
@pytest.mark.parametrize("algorithm", HOSTS)
def test_latent_loss_reaches_the_encoder_rollout_and_head_only(algorithm):
    model = make(algorithm)
    model.learning_starts = 100  # collect without updating
    model.learn(20)
    batch = model.replay_buffer.sample(6)
    observations, targets = model._augment_observations(batch, pad=4)
    for parameter in trained_parameters(model).values():
        parameter.grad = None
    model.auxiliary(model.encode(observations), targets)[0].backward()
    named = trained_parameters(model)
    reached = {n for n, p in named.items() if p.grad is not None and bool(p.grad.abs().sum() > 0)}
    prefix = {DrQv2EF: "encoder.", TDMPC2EF: "world_model.encoder."}.get(algorithm, "critic.features_extractor.")
    groups = {
        "encoder": {n for n in named if n.startswith(prefix)},
        "rollout": {n for n in named if n.startswith("auxiliary.ef.rollout_block.")},
        "head": {n for n in named if n.startswith("auxiliary.ef.head.")},
    }
    for group, names in groups.items():
        assert names and names <= reached, f"{group}: not reached {sorted(names - reached)}"
    assert reached == set().union(*groups.values()), sorted(reached - set().union(*groups.values()))
    target_tensors = {id(t) for t in model.auxiliary.target_encoder.buffers()}
    assert target_tensors and not any(t.requires_grad for t in model.auxiliary.target_encoder.buffers())
    stepped = {id(p) for optimiser in optimisers(model) for group in optimiser.param_groups for p in group["params"]}
    assert stepped and not (stepped & target_tensors)


@pytest.mark.parametrize("algorithm", HOSTS)
def test_save_load_is_exact_and_takes_the_same_next_update(algorithm, tmp_path):
    model = make(algorithm)
    model.learn(20)
    model.save(tmp_path / "model")
    model.save_replay_buffer(tmp_path / "buffer")
    loaded = type(model).load(tmp_path / "model", env=env_for(algorithm))
    loaded.load_replay_buffer(tmp_path / "buffer")
    saved, restored = state(model), state(loaded)
    assert saved.keys() == restored.keys() and any("target_encoder.encoder." in n for n in saved)
    for name in saved:
        assert th.equal(saved[name], restored[name]), name
    for one in (model, loaded):
        one.set_logger(configure(None, []))
        np.random.seed(3)
        th.manual_seed(3)
        one.train(gradient_steps=2, batch_size=one.batch_size)
    after, after_loaded = state(model), state(loaded)
    assert any(not th.equal(saved[n], after[n]) for n in saved if "target_encoder" in n)
    for name in after:
        assert th.equal(after[name], after_loaded[name]), name


@pytest.mark.parametrize("algorithm", [DrQv2EF, SACEF])
def test_the_probe_decoder_learns_alone_and_opens_the_saliency_tools(algorithm):
    model = make(algorithm)
    model.learn(20)
    ef = model.ef
    h_scene, h_agent = ef.split(model.encode(th.as_tensor(model.observation_space.sample()[None])))
    with pytest.raises(ValueError, match=r"probe decoder, which is not trained yet.*fit_probe"):
        decoder_saliency(ef, h_scene, h_agent)
    before = state(model)
    losses = fit_probe(model, steps=30, batch_size=6)
    after = state(model)
    changed = {n for n in before if not th.equal(before[n], after[n])}
    assert changed and all(".ef.decoder." in n or n.endswith("ef.probe_steps") for n in changed), sorted(changed)
    assert int(ef.probe_steps) == 30 and np.mean(losses[-5:]) < np.mean(losses[:5])
    assert all(p.grad is None for p in ef.decoder.parameters())
    saliency = decoder_saliency(ef, h_scene, h_agent)
    assert saliency.agent.shape == (32, 32) and saliency.agent_patches.max() > 0


@pytest.mark.filterwarnings("ignore:learning_starts=100 is not below")
@pytest.mark.parametrize("algorithm", [DrQv2EF, TDMPC2EF])
def test_compiled_latent_updates_equal_eager_ones_without_graph_breaks(algorithm):
    th._dynamo.reset()
    counters.clear()
    models = [make(algorithm), make(algorithm, compile={"backend": "aot_eager"})]
    filler = make(algorithm)
    filler.learning_starts = 100
    filler.learn(20)
    samples = [filler.replay_buffer.sample(6) for _ in range(2)]
    logs = []
    for model in models:
        th.manual_seed(1)
        model.policy.set_training_mode(True)
        logs.append([model._update(sample) for sample in samples])
    for eager, compiled in zip(*logs, strict=True):
        for key, value in eager.items():
            th.testing.assert_close(compiled[key], value, rtol=1e-5, atol=1e-6)
    eager_state, compiled_state = (state(model) for model in models)
    for name, value in eager_state.items():
        th.testing.assert_close(compiled_state[name], value, rtol=1e-5, atol=1e-6, msg=lambda m, n=name: f"{n}: {m}")
    assert counters["stats"]["unique_graphs"] == 2  # the host loss and the actor / policy-prior loss, once each
    th._dynamo.reset()
