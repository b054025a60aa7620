"""One training call into sheeprl: its configuration resolved and checked, then its entry point run here."""

from __future__ import annotations

from typing import Any

import torch as th

from sb3_ef.dreamerv3.config import Session, set_session


def resolved_config(cfg: Any, session: Session, buffer_in_checkpoint: bool = True) -> Any:
    """``cfg`` with the session set, merged into a resumed run's as sheeprl's resume does, resolved and checked."""
    from omegaconf import OmegaConf, open_dict
    from sheeprl.cli import check_configs, resume_from_checkpoint
    from sheeprl.utils.utils import dotdict

    set_session(cfg, session)
    if session.resume_from is not None:
        cfg = resume_from_checkpoint(cfg)
        set_session(cfg, session)  # the resumed run's own session, not the one its configuration recorded
        with open_dict(cfg):
            cfg.buffer.checkpoint = buffer_in_checkpoint
    resolved = dotdict(OmegaConf.to_container(cfg, resolve=True, throw_on_missing=True))
    check_configs(resolved)
    return resolved


def run(resolved: Any) -> None:
    """Run sheeprl's Dreamer-v3 on ``resolved``, putting back the process-wide torch settings sheeprl changes."""
    from sheeprl.cli import run_algorithm

    settings = (
        th.distributions.Distribution._validate_args,
        th.get_float32_matmul_precision(),
        th.backends.cudnn.benchmark,
        th.backends.cudnn.deterministic,
        th.are_deterministic_algorithms_enabled(),
        th.is_deterministic_algorithms_warn_only_enabled(),
    )
    try:
        run_algorithm(resolved)
    finally:
        validate_args, matmul_precision, benchmark, deterministic, algorithms, warn_only = settings
        th.distributions.Distribution.set_default_validate_args(validate_args)
        th.set_float32_matmul_precision(matmul_precision)
        th.backends.cudnn.benchmark, th.backends.cudnn.deterministic = benchmark, deterministic
        th.use_deterministic_algorithms(algorithms, warn_only=warn_only)
