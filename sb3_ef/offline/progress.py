"""The progress bars of ``collect``, ``pretrain`` and the held-out evaluation: tqdm when installed and wanted."""

from __future__ import annotations

from typing import Any


def make_progress_bar(total: int, description: str, unit: str, enabled: bool = True, initial: int = 0) -> Any:
    """A tqdm bar over ``total`` items starting at ``initial``, or None when ``enabled`` is False or tqdm is not
    installed (callers update it only when it is not None)."""
    if not enabled:
        return None
    try:
        from tqdm.auto import tqdm
    except ImportError:
        return None
    return tqdm(total=total, initial=initial, desc=description, unit=unit)
