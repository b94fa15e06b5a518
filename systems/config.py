"""Configuration errors: the one exception a user-facing command turns into a one-line message."""


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
