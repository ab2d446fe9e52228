"""Every error the package raises on purpose; the CLI turns them into one-line messages."""


class DcsmsError(Exception):
    """Base class: a user-facing error with a one-line message."""


class ConfigError(DcsmsError):
    """An invalid configuration value, key or file; the message names the field and the file."""


class ModeError(DcsmsError):
    """An unknown control-mode name."""


class GeometryError(DcsmsError):
    """A sensor or drive matrix that is singular or badly conditioned."""


class BagError(DcsmsError):
    """A bag that cannot be read or written; the message names the file."""
