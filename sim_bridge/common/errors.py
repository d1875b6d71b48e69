"""
The exceptions of the simulator package, in one place.

Each says what went wrong in its message (file, key, expected value; the goal out of reach).
"""


class ConfigError(ValueError):
    """A configuration file or mapping is unreadable or does not match its schema."""


class UnreachableError(ValueError):
    """A Cartesian goal has no joint solution inside the joint limits."""
