"""TD-MPC2's update and planning (nicklashansen/tdmpc2: ``tdmpc2.py``'s ``_update``, ``_td_target``, ``update_pi``,
``_plan`` and ``_estimate_value``; ``common/world_model.py``, ``layers.py``, ``math.py``, ``scale.py``), transcribed for
one pixel task without termination, independently of sb3-ef's code, and given a copy of an sb3-ef world model's
weights. Its Q-ensemble is vectorised as the authors' (``torch.vmap`` over stacked parameters). Observations come
augmented (the authors' ``ShiftAug`` is left out: the tests and the benchmark give both sides the same batch).

The reference of tests/tdmpc2/test_tdmpc2_update_reference.py, and the authors' update and planner in
benchmarks/precision.py.
"""

from __future__ import annotations

import copy

import torch
import torch.nn.functional as F
from torch import nn

from sb3_ef.tdmpc2.world_model import WorldModel

# common/math.py


def symlog(x):
    return torch.sign(x) * torch.log(1 + torch.abs(x))


def symexp(x):
    return torch.sign(x) * (torch.exp(torch.abs(x)) - 1)


def two_hot(x, num_bins, vmin, vmax):
    bin_size = (vmax - vmin) / (num_bins - 1)
    x = torch.clamp(symlog(x), vmin, vmax).squeeze(1)
    bin_idx = torch.floor((x - vmin) / bin_size)
    bin_offset = ((x - vmin) / bin_size - bin_idx).unsqueeze(-1)
    soft_two_hot = torch.zeros(x.shape[0], num_bins, device=x.device, dtype=x.dtype)
    bin_idx = bin_idx.long()
    soft_two_hot = soft_two_hot.scatter(1, bin_idx.unsqueeze(1), 1 - bin_offset)
    return soft_two_hot.scatter(1, (bin_idx.unsqueeze(1) + 1) % num_bins, bin_offset)


def two_hot_inv(x, num_bins, vmin, vmax):
    bins = torch.linspace(vmin, vmax, num_bins, device=x.device, dtype=x.dtype)
    return symexp(torch.sum(F.softmax(x, dim=-1) * bins, dim=-1, keepdim=True))


def gaussian_logprob(eps, log_std):
    return (-0.5 * eps.pow(2) - log_std - 0.9189385175704956).sum(-1, keepdim=True)


def squash(mu, pi, log_pi):
    mu, pi = torch.tanh(mu), torch.tanh(pi)
    return mu, pi, log_pi - torch.log(F.relu(1 - pi.pow(2)) + 1e-6).sum(-1, keepdim=True)


# common/layers.py


class NormedLinear(nn.Linear):
    def __init__(self, *args, dropout=0.0, act=None, **kwargs):
        super().__init__(*args, **kwargs)
        self.ln = nn.LayerNorm(self.out_features)
        self.act = nn.Mish(inplace=False) if act is None else act
        self.dropout = nn.Dropout(dropout, inplace=False) if dropout else None

    def forward(self, x):
        x = super().forward(x)
        if self.dropout:
            x = self.dropout(x)
        return self.act(self.ln(x))


class SimNorm(nn.Module):
    def __init__(self, dim):
        super().__init__()
        self.dim = dim

    def forward(self, x):
        shp = x.shape
        return F.softmax(x.view(*shp[:-1], -1, self.dim), dim=-1).view(*shp)


def mlp(in_dim, mlp_dims, out_dim, act=None, dropout=0.0):
    dims = [in_dim, *mlp_dims, out_dim]
    layers = [NormedLinear(dims[i], dims[i + 1], dropout=dropout * (i == 0)) for i in range(len(dims) - 2)]
    layers.append(NormedLinear(dims[-2], dims[-1], act=act) if act else nn.Linear(dims[-2], dims[-1]))
    return nn.Sequential(*layers)


class PixelPreprocess(nn.Module):
    def forward(self, x):
        return x.div(255.0).sub(0.5)


def conv(in_channels, num_channels, act):
    return nn.Sequential(
        PixelPreprocess(),
        nn.Conv2d(in_channels, num_channels, 7, stride=2), nn.ReLU(inplace=False),
        nn.Conv2d(num_channels, num_channels, 5, stride=2), nn.ReLU(inplace=False),
        nn.Conv2d(num_channels, num_channels, 3, stride=2), nn.ReLU(inplace=False),
        nn.Conv2d(num_channels, num_channels, 3, stride=1), nn.Flatten(), act,
    )  # fmt: skip


class Ensemble(nn.Module):
    """The authors' vectorised ensemble: one module called by ``torch.vmap`` on the members' stacked parameters."""

    def __init__(self, modules):
        super().__init__()
        stacked, _ = torch.func.stack_module_state(modules)
        self.names = list(stacked)
        self.params = nn.ParameterList(stacked.values())
        self.module = copy.deepcopy(modules[0]).to("meta")

    def _call(self, params, x):
        return torch.func.functional_call(self.module, dict(zip(self.names, params, strict=True)), (x,))

    def forward(self, x, params=None):
        params = tuple(self.params) if params is None else params
        return torch.vmap(self._call, (0, None), randomness="different")(params, x)


def copy_weights(reference: nn.Module, ours: nn.Module) -> None:
    """Copy the parameters of ``ours`` into ``reference``, in the order both modules list them."""
    with torch.no_grad():
        for mine, theirs in zip(reference.parameters(), ours.parameters(), strict=True):
            mine.copy_(theirs)


class RefTDMPC2:
    """The authors' agent on one pixel task, its weights copied from ``model`` (which this class never calls)."""

    def __init__(self, model: WorldModel, *, lr, horizon, gamma, tau, rho, entropy_coef, grad_clip_norm,
                 consistency_coef, reward_coef, value_coef, encoder_lr_scale, dropout, planner):  # fmt: skip
        self.horizon, self.discount, self.tau, self.rho = horizon, gamma, tau, rho
        self.entropy_coef, self.grad_clip_norm, self.planner = entropy_coef, grad_clip_norm, planner
        self.coefs = (consistency_coef, reward_coef, value_coef)
        two_hot_ = model.two_hot
        self.bins = (two_hot_.num_bins, two_hot_.vmin, two_hot_.vmax)
        self.action_dim, self.num_q = model.action_dim, model.num_q
        self.log_std_min, self.log_std_dif = model.log_std_min, model.log_std_max - model.log_std_min
        latent, action = model.latent_dim, model.action_dim
        mlp_dim = model.pi_head[0][0].out_features
        simnorm = SimNorm(model.encoder[-1].group_dim)
        self._encoder = conv(model.encoder[0].in_channels, model.encoder[0].out_channels, simnorm)
        self._dynamics = mlp(latent + action, [mlp_dim] * 2, latent, act=SimNorm(simnorm.dim))
        self._reward = mlp(latent + action, [mlp_dim] * 2, self.bins[0])
        self._pi = mlp(latent, [mlp_dim] * 2, 2 * action)
        qs = [mlp(latent + action, [mlp_dim] * 2, self.bins[0], dropout=dropout) for _ in range(model.num_q)]
        ours = (model.encoder, model.dynamics, model.reward_head, model.pi_head, *model.q_heads)
        for reference, mine in zip((self._encoder, self._dynamics, self._reward, self._pi, *qs), ours, strict=True):
            copy_weights(reference, mine)
        self._Qs = Ensemble(qs)
        self._target_Qs_params = [param.detach().clone() for param in self._Qs.params]
        self.modules = nn.ModuleList([self._encoder, self._dynamics, self._reward, self._pi, self._Qs])
        self.optim = torch.optim.Adam(
            [
                {"params": self._encoder.parameters(), "lr": lr * encoder_lr_scale},
                {"params": self._dynamics.parameters()},
                {"params": self._reward.parameters()},
                {"params": self._Qs.parameters()},
            ],
            lr=lr,
        )
        self.pi_optim = torch.optim.Adam(self._pi.parameters(), lr=lr, eps=1e-5)
        self.scale = torch.ones(1)
        self._prev_mean = torch.zeros(planner["horizon"], action)

    # common/world_model.py

    def encode(self, obs):
        if obs.ndim == 5:
            return torch.stack([self._encoder(o) for o in obs])
        return self._encoder(obs)

    def next(self, z, a):
        return self._dynamics(torch.cat([z, a], dim=-1))

    def reward(self, z, a):
        return self._reward(torch.cat([z, a], dim=-1))

    def pi(self, z):
        mean, log_std = self._pi(z).chunk(2, dim=-1)
        log_std = self.log_std_min + 0.5 * self.log_std_dif * (torch.tanh(log_std) + 1)
        eps = torch.randn_like(mean)
        log_prob = gaussian_logprob(eps, log_std)
        scaled_log_prob = log_prob * eps.shape[-1]
        action = mean + eps * log_std.exp()
        mean, action, log_prob = squash(mean, action, log_prob)
        entropy_scale = scaled_log_prob / (log_prob + 1e-8)
        return action, {"mean": mean, "scaled_entropy": -log_prob * entropy_scale}

    def Q(self, z, a, return_type="min", target=False, detach=False):
        z = torch.cat([z, a], dim=-1)
        if target:
            out = self._Qs(z, tuple(self._target_Qs_params))
        elif detach:
            out = self._Qs(z, tuple(param.detach() for param in self._Qs.params))
        else:
            out = self._Qs(z)
        if return_type == "all":
            return out
        qidx = torch.randperm(self.num_q, device=out.device)[:2]
        Q = two_hot_inv(out[qidx], *self.bins)
        return Q.min(0).values if return_type == "min" else Q.sum(0) / 2

    # tdmpc2.py

    @torch.no_grad()
    def _td_target(self, next_z, reward):
        action, _ = self.pi(next_z)
        return reward + self.discount * self.Q(next_z, action, return_type="min", target=True)

    def update(self, obs, action, reward):
        """One update on augmented observations ``(H+1, B, C, h, w)``, actions ``(H, B, A)``, rewards ``(H, B, 1)``."""
        with torch.no_grad():
            next_z = self.encode(obs[1:])
            td_targets = self._td_target(next_z, reward)
        self.modules.train()
        zs = torch.empty(self.horizon + 1, obs.shape[1], next_z.shape[-1], device=obs.device)
        z = self.encode(obs[0])
        zs[0] = z
        consistency_loss = 0
        for t, (_action, _next_z) in enumerate(zip(action.unbind(0), next_z.unbind(0), strict=True)):
            z = self.next(z, _action)
            consistency_loss = consistency_loss + F.mse_loss(z, _next_z) * self.rho**t
            zs[t + 1] = z
        _zs = zs[:-1]
        qs = self.Q(_zs, action, return_type="all")
        reward_preds = self.reward(_zs, action)
        reward_loss, value_loss = 0, 0
        for t, (rew_pred, rew, td_target, qs_t) in enumerate(
            zip(reward_preds.unbind(0), reward.unbind(0), td_targets.unbind(0), qs.unbind(1), strict=True)
        ):
            reward_loss = reward_loss + self.soft_ce(rew_pred, rew).mean() * self.rho**t
            for q in qs_t.unbind(0):
                value_loss = value_loss + self.soft_ce(q, td_target).mean() * self.rho**t
        consistency_loss = consistency_loss / self.horizon
        reward_loss = reward_loss / self.horizon
        value_loss = value_loss / (self.horizon * self.num_q)
        consistency_coef, reward_coef, value_coef = self.coefs
        total_loss = consistency_coef * consistency_loss + reward_coef * reward_loss + value_coef * value_loss
        total_loss.backward()
        torch.nn.utils.clip_grad_norm_(self.modules.parameters(), self.grad_clip_norm)
        self.optim.step()
        self.optim.zero_grad(set_to_none=True)
        pi_loss = self.update_pi(zs.detach())
        torch._foreach_lerp_(self._target_Qs_params, [param.detach() for param in self._Qs.params], self.tau)
        self.modules.eval()
        losses = {"consistency_loss": consistency_loss, "reward_loss": reward_loss, "value_loss": value_loss}
        return {**{name: loss.detach() for name, loss in losses.items()}, "pi_loss": pi_loss.detach()}

    def soft_ce(self, pred, target):
        return -(two_hot(target, *self.bins) * F.log_softmax(pred, dim=-1)).sum(-1, keepdim=True)

    def update_pi(self, zs):
        action, info = self.pi(zs)
        qs = self.Q(zs, action, return_type="avg", detach=True)
        self.update_scale(qs[0])
        qs = qs / self.scale
        rho = torch.pow(self.rho, torch.arange(len(qs), device=qs.device))
        pi_loss = (-(self.entropy_coef * info["scaled_entropy"] + qs).mean(dim=(1, 2)) * rho).mean()
        pi_loss.backward()
        torch.nn.utils.clip_grad_norm_(self._pi.parameters(), self.grad_clip_norm)
        self.pi_optim.step()
        self.pi_optim.zero_grad(set_to_none=True)
        return pi_loss

    def update_scale(self, x):
        """common/scale.py's ``RunningScale.update``: the 5-95 percentile range, at least 1, by linear positions."""
        x = x.detach().flatten(1, x.ndim - 1)
        in_sorted = torch.sort(x, dim=0).values
        positions = torch.tensor([5.0, 95.0]) * (x.shape[0] - 1) / 100
        floored = torch.floor(positions)
        ceiled = torch.where(floored + 1 > x.shape[0] - 1, x.shape[0] - 1, floored + 1)
        weight = (positions - floored).unsqueeze(1)
        percentiles = in_sorted[floored.long()] * (1 - weight) + in_sorted[ceiled.long()] * weight
        self.scale.lerp_(torch.clamp(percentiles[1] - percentiles[0], min=1.0), self.tau)

    @torch.no_grad()
    def estimate_value(self, z, actions):
        """``_estimate_value``: actions ``(H, N, A)`` from latents ``(N, L)``; values ``(N, 1)``."""
        G, discount = 0, 1
        for t in range(self.planner["horizon"]):
            reward = two_hot_inv(self.reward(z, actions[t]), *self.bins)
            z = self.next(z, actions[t])
            G = G + discount * reward
            discount = discount * self.discount
        action, _ = self.pi(z)
        return G + discount * self.Q(z, action, return_type="avg")

    @torch.no_grad()
    def plan(self, obs, t0=False, eval_mode=False):
        """``_plan``: one action ``(A,)`` for one observation ``(1, C, h, w)``, warm-started unless ``t0``."""
        horizon, num_samples, num_pi_trajs, num_elites = (
            self.planner[name] for name in ("horizon", "num_samples", "num_pi_trajs", "num_elites")
        )
        min_std, max_std, temperature = self.planner["min_std"], self.planner["max_std"], self.planner["temperature"]
        z = self.encode(obs)
        if num_pi_trajs > 0:
            pi_actions = torch.empty(horizon, num_pi_trajs, self.action_dim)
            _z = z.repeat(num_pi_trajs, 1)
            for t in range(horizon - 1):
                pi_actions[t], _ = self.pi(_z)
                _z = self.next(_z, pi_actions[t])
            pi_actions[-1], _ = self.pi(_z)
        z = z.repeat(num_samples, 1)
        mean = torch.zeros(horizon, self.action_dim)
        std = torch.full((horizon, self.action_dim), max_std, dtype=torch.float)
        if not t0:
            mean[:-1] = self._prev_mean[1:]
        actions = torch.empty(horizon, num_samples, self.action_dim)
        if num_pi_trajs > 0:
            actions[:, :num_pi_trajs] = pi_actions
        for _ in range(self.planner["iterations"]):
            r = torch.randn(horizon, num_samples - num_pi_trajs, self.action_dim)
            actions[:, num_pi_trajs:] = (mean.unsqueeze(1) + std.unsqueeze(1) * r).clamp(-1, 1)
            value = self.estimate_value(z, actions).nan_to_num(0)
            elite_idxs = torch.topk(value.squeeze(1), num_elites, dim=0).indices
            elite_value, elite_actions = value[elite_idxs], actions[:, elite_idxs]
            max_value = elite_value.max(0).values
            score = torch.exp(temperature * (elite_value - max_value))
            score = score / score.sum(0)
            mean = (score.unsqueeze(0) * elite_actions).sum(dim=1) / (score.sum(0) + 1e-9)
            std = (score.unsqueeze(0) * (elite_actions - mean.unsqueeze(1)) ** 2).sum(dim=1) / (score.sum(0) + 1e-9)
            std = std.sqrt().clamp(min_std, max_std)
        gumbels = -torch.empty_like(score.squeeze(1)).exponential_().log()
        rand_idx = (score.squeeze(1).log() + gumbels).softmax(0).argmax(-1)
        a, std = torch.index_select(elite_actions, 1, rand_idx.reshape(1)).squeeze(1)[0], std[0]
        if not eval_mode:
            a = a + std * torch.randn(self.action_dim)
        self._prev_mean.copy_(mean)
        return a.clamp(-1, 1)


def reference_of(model, dropout: float | None = None) -> RefTDMPC2:
    """The reference agent of an sb3-ef ``TDMPC2`` (its settings, its world model's weights)."""
    policy = model.policy
    planner = policy.planner
    kwargs = policy._constructor_kwargs
    return RefTDMPC2(
        policy.world_model, lr=model.lr_schedule(1), horizon=model.horizon, gamma=model.gamma, tau=model.tau,
        rho=model.rho, entropy_coef=model.entropy_coef, grad_clip_norm=model.max_grad_norm,
        consistency_coef=model.consistency_coef, reward_coef=model.reward_coef, value_coef=model.value_coef,
        encoder_lr_scale=kwargs["encoder_lr_scale"], dropout=kwargs["dropout"] if dropout is None else dropout,
        planner={name: getattr(planner, name) for name in (
            "horizon", "iterations", "num_samples", "num_elites", "num_pi_trajs", "min_std", "max_std", "temperature"
        )},
    )  # fmt: skip
