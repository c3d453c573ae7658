"""Errors every layer shares (a leaf module: it imports nothing of aslexp)."""

from __future__ import annotations


class DataError(ValueError):
    """Bad or inconsistent input data; the message names the file, the field and what was expected."""


class ConfigError(ValueError):
    """A configuration value of the wrong type or out of range: bad input (exit 2). The message
    names the key, the value given and what is expected: ``ppo.total_steps=abc: expected ...``."""


class SimulationDiverged(RuntimeError):
    """A simulation blew up (a non-finite state, or a joint far faster than any engine clamps): an
    error, never a score (exit 1). The message says where and when, and what to change."""
