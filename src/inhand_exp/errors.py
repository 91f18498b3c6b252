"""The refusals the ``inhand-exp`` app reports as one line each (exit code 2), defined apart from
the modules that raise them so that the app can catch them without importing torch or pandas:
a typo or a refused config is answered within about a second."""

from __future__ import annotations


class CheckpointError(ValueError):
    """A checkpoint that cannot be read, or does not fit this configuration."""


class GoalsError(ValueError):
    """A goal file that cannot be used, with the row and column at fault."""


class DemonstrationsError(ValueError):
    """A demonstrations file that cannot be read, or does not fit this configuration."""
