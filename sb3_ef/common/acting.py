"""Acting with a trained model one observation at a time, as an evaluation does: ``predict``'s state carried.

SB3's ``predict(observation, state, episode_start)`` returns a state that its next call takes (a recurrent policy's
hidden state; TD-MPC2's warm-start plans). A loop that drops it acts otherwise than the evaluations did.
"""

from __future__ import annotations

from typing import Any

import numpy as np


class EpisodeActor:
    """``model.predict`` over one episode at a time, each call taking the state the previous one returned.

    :param model: anything with SB3's ``predict`` (an algorithm or a policy).
    :param deterministic: as ``predict``'s.
    """

    def __init__(self, model: Any, deterministic: bool = True) -> None:
        self.model = model
        self.deterministic = deterministic
        self.state: tuple[np.ndarray, ...] | None = None
        self._episode_start = True

    def reset(self) -> None:
        """A new episode begins: the next call starts from no state."""
        self.state, self._episode_start = None, True

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        """The action for ``observation`` (one env's, unbatched)."""
        action, self.state = self.model.predict(
            observation,
            state=self.state,
            episode_start=np.array([self._episode_start]),
            deterministic=self.deterministic,
        )
        self._episode_start = False
        return action
