"""The progress bars of ``collect``, ``pretrain`` and the held-out evaluation: tqdm when installed and wanted."""

from __future__ import annotations

from typing import Any


class _NoBar:
    """The part of tqdm's interface the callers use, doing nothing."""

    def update(self, n: int = 1) -> None: ...

    def set_postfix(self, **values: Any) -> None: ...

    def close(self) -> None: ...


def make_progress_bar(total: int, description: str, unit: str, enabled: bool = True, initial: int = 0) -> Any:
    """A tqdm bar over ``total`` items from ``initial``; a silent one when not ``enabled`` or without tqdm."""
    try:
        from tqdm.auto import tqdm
    except ImportError:
        return _NoBar()
    return tqdm(total=total, initial=initial, desc=description, unit=unit, disable=not enabled)
