"""DrQ-v2, DrQv2-EF and SEAR against examples/drqv2_ef_single_file.py: DrQ-v2's update (facebookresearch/drqv2) and
the EF authors' loss transcribed independently of sb3-ef's code, run beside the model's own update from its weights.

The models act for 40 steps in TerminatingToyEnv (episodes that terminate, episodes cut by the time limit, one still
running), into a replay buffer small enough to wrap around, and every transition SB3 hands to the buffer's ``add`` is
recorded on its way. Each update is the model's own ``train(1, batch_size)``. The reference takes from it only what
is drawn at random: which stored steps the buffer drew (found by their observations among the recorded ones), the
shift of each image (found by comparing the reference's own images with what the encoder received), the rollout
length k (from EF's targets) and torch's random state once the batch is augmented (for the exploration noise).
Everything else it computes from the recorded episodes: n-step rewards, discounts, the terminal cut, next
observations, frame t+k, EF's actions and which samples are valid; SEAR's agent masks come from the envs' infos.
Every loss and every parameter after each of three updates agree to float rounding, and the batches are checked to
hold a termination within n steps, a window cut by a time limit or the running episode's end, and EF samples past
their episode's end.

Mutations of the package tried by hand on a copy of the tree, each failing this test (the unmutated copy passes):
(a) ``(1.0 - batch.dones)`` dropped from the critic target (``DrQv2._critic_loss``): DrQv2, DrQv2EF and SEAR fail
    (critic_loss at the first update);
(b) EF's valid mask ignored (all-true weights in ``ForesightLoss.prepare``, or none passed to ``_weighted_mean`` in
    ``EgoForesight.loss``): DrQv2EF fails (ef_loss);
(c) the n-step discount one power of gamma off in ``sampling.py`` (``discounts`` gamma^(m+1) or gamma^(m-1), or the
    rewards weighted gamma^1 .. gamma^n): all three fail (critic_loss);
(d) the n-step sum read past a termination in ``BatchSampler._gather`` (the ``cummin`` that ends an episode's run of
    steps dropped: the next observation is no shift of observation t + m; the rewards read from unmasked rows:
    critic_loss): all three fail;
(e) time limits taken for terminations (``~timeouts`` dropped from ``dones``): all three fail (critic_loss).
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import pytest
import torch as th
from torch import nn
from torch.nn import functional as F

from examples.drqv2_ef_single_file import (
    Actor,
    Batch,
    Config,
    Critic,
    DrQv2EFAgent,
    EgoForesight,
    Encoder,
    Episode,
    augment,
    make_batch,
    n_step_transition,
    shift,
)
from sb3_ef import SEAR, DrQv2, DrQv2EF
from sb3_ef.common.buffers import MASKS_INFO_KEY
from sb3_ef.envs.toy import ToyAgentEnv
from tests.helpers.drqv2 import TerminatingToyEnv
from tests.helpers.references import assert_parameters_close

FRAME, BATCH, HIDDEN, TRUNK, FEATURES, AGENT = 32, 8, 16, 8, 64, 8
# Values far from the defaults, so that a swapped constant shows; n_steps above frame_stack + 1, so that an n-step
# window past an episode's last step reaches the next episode's first step in the buffer's ring.
CONFIG = Config(
    learning_rate=2e-3, gamma=0.8, n_steps=5, tau=0.3, std_schedule=(0.9, 0.2, 40), target_noise_clip=0.2,
    features_dim=FEATURES, trunk_dim=TRUNK, hidden_dims=(HIDDEN, HIDDEN), beta=0.7, horizon=3, agent_dim=AGENT,
    rollout_hidden_dims=(16,), decoder_channels=8,
)  # fmt: skip
EPISODE_STEPS, TERMINATE_AFTER, BUFFER_FRAMES, ACTING_STEPS = 10, 6, 40, 40
TIMESTEPS = (0, 17, 60)  # the std of each update: on the schedule's slope, then past its end
# Adam divides by the root of the squared gradient: a gradient at rounding level moves a weight by up to the learning
# rate, in a direction rounding decides. A twentieth of an Adam step is far below what a change in the maths moves.
ADAM_ROUNDING = CONFIG.learning_rate / 20
OFFSETS = th.tensor(
    [(dy, dx) for dy in range(-CONFIG.pad, CONFIG.pad + 1) for dx in range(-CONFIG.pad, CONFIG.pad + 1)]
)


class Recording:
    """The transitions SB3 hands to ``buffer.add`` (one env), grouped into episodes, with each observation's masks."""

    def __init__(self, buffer: Any):
        self.episodes: list[Episode] = []
        self.masks: list[list[np.ndarray]] = []
        self.open = False  # the last episode goes on
        add = buffer.add

        def recorded_add(obs, next_obs, action, reward, done, infos) -> None:
            self.record(obs[0], next_obs[0], action[0], reward[0], bool(done[0]), infos[0])
            add(obs, next_obs, action, reward, done, infos)

        buffer.add = recorded_add

    def record(self, obs: np.ndarray, next_obs: np.ndarray, action, reward, done: bool, info: dict) -> None:
        last = self.episodes[-1] if self.episodes else None
        if last is None or not self.open or not np.array_equal(obs, last.observations[-1]):
            last = Episode([obs.copy()], [], [], terminated=False)
            self.episodes.append(last)
            self.masks.append([info[MASKS_INFO_KEY][:-1]] if MASKS_INFO_KEY in info else [])
        last.observations.append(next_obs.copy())
        last.actions.append(np.asarray(action, dtype=np.float32).copy())
        last.rewards.append(float(np.float32(reward)))
        last.terminated = done and not info.get("TimeLimit.truncated", False)
        self.open = not done
        if MASKS_INFO_KEY in info:
            self.masks[-1].append(info[MASKS_INFO_KEY][1:])

    def steps(self, observations: th.Tensor) -> list[tuple[int, int]]:
        """(episode, step) of each stacked observation, found among the recorded ones."""
        where = {
            obs.tobytes(): (e, t)
            for e, episode in enumerate(self.episodes)
            for t, obs in enumerate(episode.observations[:-1])
        }
        assert len(where) == sum(len(episode.actions) for episode in self.episodes), "two steps share an observation"
        return [where[obs.tobytes()] for obs in observations.cpu().numpy()]


def make_model(algorithm: type) -> tuple[DrQv2, Recording]:
    cfg = CONFIG
    std = "linear({},{},{})".format(*cfg.std_schedule)
    arguments: dict[str, Any] = {
        "learning_rate": cfg.learning_rate, "gamma": cfg.gamma, "n_steps": cfg.n_steps, "tau": cfg.tau,
        "exploration_std": std, "target_noise_clip": cfg.target_noise_clip, "buffer_size": BUFFER_FRAMES,
        "batch_size": BATCH, "learning_starts": ACTING_STEPS + 1, "seed": 0, "device": "cpu",
        "policy_kwargs": {"net_arch": list(cfg.hidden_dims), "trunk_dim": cfg.trunk_dim},
    }  # fmt: skip
    if algorithm is DrQv2EF:
        arguments.update(ef_horizon=cfg.horizon, babbling_steps=0, beta=cfg.beta)
        ef_kwargs = {"rollout_hidden_dims": cfg.rollout_hidden_dims, "decoder_channels": cfg.decoder_channels}
        arguments["policy_kwargs"].update(features_dim=FEATURES, agent_dim=AGENT, ef_kwargs=ef_kwargs)
    elif algorithm is SEAR:
        arguments["policy_kwargs"].update(features_dim=FEATURES)
    toy = ToyAgentEnv(size=FRAME, max_episode_steps=EPISODE_STEPS, agent_masks=algorithm is SEAR)
    model = algorithm("CnnPolicy", TerminatingToyEnv(toy, TERMINATE_AFTER), **arguments)
    recording = Recording(model.replay_buffer)
    model.learn(ACTING_STEPS)  # fills the buffer (before learning_starts: no update)
    return model, recording


@dataclasses.dataclass
class SEARBatch(Batch):
    masks: th.Tensor  # (B, k, h, w) agent masks of the observation's frames, shifted with them


class SEARReference(nn.Module):
    """sear-rl's loss on copies of sb3-ef's decoders (their layers are tested in tests/sear): the halves of the
    latent decoded to the frames in [-0.5, 0.5] and to the agent masks, squared error and BCE summed over pixels,
    averaged over the batch, weighted 1 and 0.25."""

    def __init__(self, frame_decoder: nn.Module, mask_decoder: nn.Module):
        super().__init__()
        self.frame_decoder, self.mask_decoder = frame_decoder, mask_decoder

    def forward(self, h: th.Tensor, batch: SEARBatch) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        first, second = h.chunk(2, dim=1)
        frames = th.clamp(self.frame_decoder(first), -0.5, 0.5)
        reconstruction = (frames - (batch.observations.float() / 255.0 - 0.5)).pow(2).flatten(1).sum(1).mean()
        masks = th.sigmoid(self.mask_decoder(second))
        mask = F.binary_cross_entropy(masks, batch.masks.float(), reduction="none").flatten(1).sum(1).mean()
        return 1.0 * reconstruction + 0.25 * mask, {"reconstruction_loss": reconstruction, "mask_loss": mask}


def module_pairs(model: DrQv2, reference: DrQv2EFAgent) -> dict[str, tuple[nn.Module, nn.Module]]:
    """sb3-ef's modules beside the reference's, their parameters in the same order."""
    policy = model.policy
    pairs: dict[str, tuple[nn.Module, nn.Module]] = {
        "encoder": (policy.encoder, reference.encoder),
        "actor": (policy.actor, reference.actor),
        "critic": (policy.critic, reference.critic),
        "critic_target": (policy.critic_target, reference.critic_target),
    }
    if reference.auxiliary is not None and model.auxiliary is not None:
        ef = isinstance(model, DrQv2EF)
        names = ["ef.rollout_block.net", "ef.decoder"] if ef else ["frame_decoder", "mask_decoder"]
        ours = nn.ModuleList([model.auxiliary.get_submodule(name) for name in names])
        pairs["auxiliary"] = (ours, reference.auxiliary)
    return pairs


def reference_of(model: DrQv2) -> DrQv2EFAgent:
    """The reference agent with the model's weights."""
    encoder = Encoder(9, FRAME, None if type(model) is DrQv2 else FEATURES)
    auxiliary: nn.Module | None = None
    if isinstance(model, DrQv2EF):
        auxiliary = EgoForesight(FEATURES, 2, (3, FRAME, FRAME), CONFIG)
    elif isinstance(model, SEAR):
        sear: Any = model.auxiliary
        auxiliary = SEARReference(copy.deepcopy(sear.frame_decoder), copy.deepcopy(sear.mask_decoder))
    actor, critic = Actor(encoder.repr_dim, 2, CONFIG), Critic(encoder.repr_dim, 2, CONFIG)
    reference = DrQv2EFAgent(encoder, actor, critic, auxiliary, CONFIG)
    for name, (ours, theirs) in module_pairs(model, reference).items():
        for kind in ("parameters", "buffers"):
            mine, copies = list(getattr(ours, kind)()), list(getattr(theirs, kind)())
            assert [tuple(x.shape) for x in mine] == [tuple(x.shape) for x in copies], f"{name} {kind}"
            for value, copied in zip(mine, copies, strict=True):
                copied.data.copy_(value.data)
    return reference


def parameters(model: DrQv2, reference: DrQv2EFAgent) -> dict[str, tuple[th.Tensor, th.Tensor]]:
    """Each sb3-ef parameter beside the reference's."""
    found: dict[str, tuple[th.Tensor, th.Tensor]] = {}
    for name, (ours, theirs) in module_pairs(model, reference).items():
        for index, pair in enumerate(zip(ours.parameters(), theirs.parameters(), strict=True)):
            found[f"{name}.{index}"] = pair
    return found


@contextmanager
def watching(model: DrQv2) -> Iterator[dict[str, Any]]:
    """What the model's next update draws: its batch, the encoder's inputs, torch's random state at the first
    encoding (the augmentation done), EF's rollout lengths."""
    seen: dict[str, Any] = {"inputs": []}
    buffer = model.replay_buffer
    assert buffer is not None
    sample = buffer.sample

    def recorded_sample(*args: Any, **kwargs: Any) -> Any:
        seen["batch"] = sample(*args, **kwargs)
        return seen["batch"]

    def encoder_input(module: nn.Module, inputs: tuple[th.Tensor, ...]) -> None:
        if not seen["inputs"]:
            seen["rng_state"] = th.get_rng_state()
        seen["inputs"].append(inputs[0].detach().clone())

    def auxiliary_input(module: nn.Module, inputs: tuple[Any, ...]) -> None:
        seen["steps"] = getattr(inputs[1], "steps", None)

    buffer.sample = recorded_sample
    hooks = [model.policy.encoder.register_forward_pre_hook(encoder_input)]
    if model.auxiliary is not None:
        hooks.append(model.auxiliary.register_forward_pre_hook(auxiliary_input))
    try:
        yield seen
    finally:
        del buffer.sample
        for hook in hooks:
            hook.remove()


def offsets_of(originals: th.Tensor, shifted: th.Tensor, what: str) -> th.Tensor:
    """The one (dy, dx) per sample that shifts ``originals`` (B, C, h, w) into ``shifted``."""
    found = []
    for sample, (original, result) in enumerate(zip(originals, shifted, strict=True)):
        moved = shift(original.expand(len(OFFSETS), *original.shape), OFFSETS)
        matches = OFFSETS[(moved == result).flatten(1).all(dim=1)]
        assert len(matches) == 1, f"sample {sample}: the encoder's input is {len(matches)} shifts of its {what}"
        found.append(matches[0])
    return th.stack(found)


def reference_batch(model: DrQv2, recording: Recording, seen: dict[str, Any]) -> Batch:
    """The reference's batch of the steps the model drew, shifted as the model shifted them."""
    samples = recording.steps(seen["batch"].observations)
    steps = seen.get("steps")
    k = 1
    if steps is not None:  # EF: one k per batch, as its authors draw it
        assert bool((steps == steps[0]).all()), steps
        k = int(steps[0])
    batch = make_batch(recording.episodes, samples, k, CONFIG)
    observations, next_observations = seen["inputs"]
    offsets = offsets_of(batch.observations, observations, "observation at t")
    next_offsets = offsets_of(batch.next_observations, next_observations, "observation at t + min(n, steps left)")
    augmented = augment(batch, offsets, next_offsets)
    if isinstance(model, SEAR):
        masks = th.as_tensor(np.stack([recording.masks[e][t] for e, t in samples])).to(th.uint8)
        augmented = SEARBatch(**vars(augmented), masks=shift(masks, offsets))
    return augmented


@pytest.mark.filterwarnings("ignore:learning_starts=.* no gradient update will run")
@pytest.mark.parametrize("algorithm", [DrQv2, DrQv2EF, SEAR])
def test_three_updates_match_the_single_file_reference_to_float_rounding(algorithm):
    model, recording = make_model(algorithm)
    reference = reference_of(model)
    before = {name: ours.detach().clone() for name, (ours, _) in parameters(model, reference).items()}
    for name, (ours, theirs) in parameters(model, reference).items():
        assert th.equal(ours, theirs), name
    batches = []
    for update, timesteps in enumerate(TIMESTEPS):
        model.num_timesteps = timesteps
        model.logger.name_to_value.clear()
        th.manual_seed(100 + update)
        with watching(model) as seen:
            model.train(1, BATCH)
        batch = reference_batch(model, recording, seen)
        batches.append(batch)
        th.set_rng_state(seen["rng_state"])
        expected = reference.update(batch, timesteps)
        for name, value in expected.items():
            logged = th.tensor(model.logger.name_to_value[f"train/{name}"], dtype=th.float32)
            th.testing.assert_close(logged, value, msg=lambda m, where=f"{name} at {update}": f"{where}: {m}")
        assert_parameters_close(parameters(model, reference), ADAM_ROUNDING, f"after {update}")
    after = {name: ours.detach() for name, (ours, _) in parameters(model, reference).items()}
    moved = [name for name in before if not th.equal(before[name], after[name])]
    assert len(moved) == len(before), sorted(set(before) - set(moved))
    # The batches hold what the mutations above break: terminations within n steps, windows cut without one
    # (a time limit, the running episode's newest step), and EF samples past their episode's end.
    dones, discounts = th.cat([batch.dones for batch in batches]), th.cat([batch.discounts for batch in batches])
    cut = discounts > CONFIG.gamma**CONFIG.n_steps * (1 + 1e-6)
    assert bool((dones == 1).any()) and bool((cut & (dones == 0)).any()), (dones.flatten(), discounts.flatten())
    if algorithm is DrQv2EF:
        valid = th.cat([batch.ef_valid for batch in batches])
        assert not bool(valid.all()) and bool(valid.any()), valid


def test_the_reference_sums_rewards_up_to_a_termination():
    """The reference's own n-step rule on a short terminated episode (the product is held to it above)."""
    frames = [np.full((9, 2, 2), step, dtype=np.uint8) for step in range(4)]
    episode = Episode(frames, [np.zeros(2, np.float32)] * 3, [1.0, 2.0, 4.0], terminated=True)
    reward, discount, done, next_obs = n_step_transition(episode, 0, 2, 0.5)
    assert (reward, discount, done, next_obs is frames[2]) == (2.0, 0.25, 0.0, True)
    reward, discount, done, next_obs = n_step_transition(episode, 1, 5, 0.5)
    assert (reward, discount, done, next_obs is frames[3]) == (4.0, 0.25, 1.0, True)
