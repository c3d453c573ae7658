"""What every registry of aslexp shares (keypoint formats, classifiers, engines): loading the
installed plug-ins of an entry-point group once, and importing the module a YAML names to register
something.

A leaf module: it imports nothing of aslexp but :mod:`aslexp.errors`.
"""

from __future__ import annotations

import importlib
import logging

from aslexp.errors import ConfigError

log = logging.getLogger(__name__)

_loaded_groups: set[str] = set()


def load_entry_points(group: str, what: str) -> None:
    """Run every entry point of ``group`` once per process: each names a module (imported) or a
    callable (called without arguments) that makes its registrations. A broken plug-in is logged
    (``what`` names the kind) and skipped: it must not break the built-ins."""
    if group in _loaded_groups:
        return
    _loaded_groups.add(group)
    from importlib.metadata import entry_points

    for entry in entry_points(group=group):
        try:
            target = entry.load()
        except Exception as error:  # noqa: BLE001 - a broken plug-in must not break the built-ins
            log.warning("%s plug-in %s (%s) failed to load: %s", what, entry.name, entry.value, error)
            continue
        if callable(target):
            target()


def import_registering_module(what: str, name: str, module: str) -> None:
    """Import ``module``, which registers ``name`` (a config's ``module:`` key); a module that cannot
    be imported is one line naming the kind, the name and the reason."""
    try:
        importlib.import_module(module)
    except ImportError as error:
        raise ConfigError(f"{what} {name}: module {module} could not be imported ({error})") from None
