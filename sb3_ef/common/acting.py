"""Acting with a trained model one observation at a time, carrying the state ``predict`` returns to its next call."""

from __future__ import annotations

from typing import Any

import numpy as np


class EpisodeActor:
    """``model.predict`` over one episode, each call taking the state the previous one returned."""

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
