"""The body-schema study's modules (``experiments/2026-12-body-schema``) import each other by file name, as when its
script runs: the folder goes on ``sys.path`` for the tests of this folder."""

import sys
from pathlib import Path

BODY_SCHEMA = Path(__file__).resolve().parents[2] / "experiments" / "2026-12-body-schema"
sys.path.insert(0, str(BODY_SCHEMA))
