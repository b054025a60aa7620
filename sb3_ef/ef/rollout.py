"""The Ego-Foresight rollout block: predicts the agent's future features from its actions alone."""

from __future__ import annotations

import torch as th
from torch import nn

from sb3_ef.common.layers import mlp


class RolloutBlock(nn.Module):
    """A recurrent MLP ``h_a(t+1) = FC([h_a(t), a(t)])`` in TD-MPC2's style (Linear -> LayerNorm -> Mish blocks).

    There is no residual connection: the block outputs the next agent features directly, as in the authors' code.
    Only the agent part of the features goes in, so whatever it predicts must be explained by the actions.

    :param agent_dim: size of the agent features ``h_a``.
    :param action_dim: size of one action.
    :param hidden_dims: widths of the hidden ``NormedLinear`` blocks.
    """

    def __init__(self, agent_dim: int, action_dim: int, hidden_dims: tuple[int, ...] | list[int] = (512, 512)):
        super().__init__()
        self.agent_dim = agent_dim
        self.action_dim = action_dim
        self.net = mlp(agent_dim + action_dim, tuple(hidden_dims), agent_dim)

    def step(self, h_agent: th.Tensor, action: th.Tensor) -> th.Tensor:
        """One step: (B, agent_dim), (B, action_dim) -> (B, agent_dim)."""
        return self.net(th.cat([h_agent, action], dim=-1))

    def forward(self, h_agent: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """Roll ``h_agent`` (B, agent_dim) through ``actions`` (B, T, action_dim); returns (B, T, agent_dim)."""
        if h_agent.dim() != 2 or h_agent.shape[1] != self.agent_dim:
            raise ValueError(f"Expected h_agent of shape (batch, {self.agent_dim}), got {tuple(h_agent.shape)}")
        if actions.dim() != 3 or actions.shape[0] != h_agent.shape[0] or actions.shape[2] != self.action_dim:
            raise ValueError(
                f"Expected actions of shape ({h_agent.shape[0]}, steps, {self.action_dim}), got {tuple(actions.shape)}"
            )
        states = []
        for t in range(actions.shape[1]):
            h_agent = self.step(h_agent, actions[:, t])
            states.append(h_agent)
        if not states:
            return h_agent.new_zeros(h_agent.shape[0], 0, self.agent_dim)
        return th.stack(states, dim=1)
