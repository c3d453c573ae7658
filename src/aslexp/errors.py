"""Errors every layer shares (a leaf module: it imports nothing of aslexp)."""

from __future__ import annotations


class DataError(ValueError):
    """Bad or inconsistent input data; the message names the file, the field and what was expected."""
