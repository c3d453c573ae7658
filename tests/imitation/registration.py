"""Registering a test-only extension module afresh (an engine, a reward error), as a user's would be."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from pathlib import Path


def fresh_registration(monkeypatch, module: str, forget: Callable[[], None]) -> Iterator[None]:
    """A test-only extension module of this folder (``module``), found through ``sys.path`` as a
    user's would be, registering afresh: ``forget`` drops its registration before and after."""
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parent))
    forget()
    sys.modules.pop(module, None)
    yield
    forget()
    sys.modules.pop(module, None)
