"""Gymnasium registration of the pixel environments (cheap: no MuJoCo import)."""


def register_envs() -> None:
    """Register the pixel environments with gymnasium (filled in by the environments module)."""
