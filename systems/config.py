"""Configuration errors (the one exception a user-facing command turns into a one-line message) and where a
configured file is looked up."""

from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parent.parent  # the checkout: models/, scenarios/, ...


class ConfigError(ValueError):
    """A scenario or system configuration that cannot be run, with a message naming the field."""


def require(condition: bool, message: str) -> None:
    """Raises ConfigError(message) unless `condition` holds."""
    if not condition:
        raise ConfigError(message)


def require_positive(value: float, name: str) -> None:
    require(value > 0, f"{name} must be positive, got {value}")


def require_non_negative(value: float, name: str) -> None:
    require(value >= 0, f"{name} must not be negative, got {value}")


def project_file(path: str | Path) -> Path:
    """A configured file's path (a model, a calibration): `path` itself if it is absolute or exists from the
    working directory, else the same relative path under the project root (so `models/...` works anywhere)."""
    path = Path(path)
    if path.is_absolute() or path.exists():
        return path
    return PROJECT_ROOT / path
