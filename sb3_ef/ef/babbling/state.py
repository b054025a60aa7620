"""What a babbling run keeps on the model: its generators, its end, and the plateau rule of adaptive babbling."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: The model attribute holding the babbling state (saved with the model, so that a resumed run continues it).
STATE_ATTRIBUTE = "_motor_babbling"


@dataclass
class Plateau:
    """Adaptive babbling's plateau: ``patience`` evaluations in a row without a score (an error) below
    ``best * (1 - min_delta)``."""

    patience: int
    min_delta: float
    best: float = math.inf
    stale: int = 0

    def update(self, score: float) -> bool:
        """Take one evaluation's score; return whether the scores have plateaued."""
        if score < self.best * (1.0 - self.min_delta):
            self.best, self.stale = score, 0
        else:
            self.stale += 1
        return self.plateaued

    @property
    def plateaued(self) -> bool:
        return self.stale >= self.patience


@dataclass
class BabblingState:
    """What a resumed run needs to continue babbling exactly: generators, end (``end_reason``) and scores."""

    rng: np.random.Generator
    eval_rng: np.random.Generator
    holdout_seed: int
    end_step: int | None = None
    end_reason: str | None = None
    plateau: Plateau | None = None
    scores: list[tuple[int, float]] = field(default_factory=list)
    next_evaluation: int = 0

    @classmethod
    def seeded(cls, seed: int | None) -> BabblingState:
        """Generators spawned from ``seed`` (fresh entropy when ``None``): the same seed babbles the same."""
        children = np.random.SeedSequence(None if seed is None else seed % 2**32).spawn(3)
        return cls(
            np.random.default_rng(children[0]),
            np.random.default_rng(children[1]),
            int(children[2].generate_state(1)[0]),
        )

    def restart(self) -> None:
        """A run that starts again from step 0 babbles again (its generators continue)."""
        self.end_step, self.end_reason, self.plateau, self.scores, self.next_evaluation = None, None, None, [], 0
