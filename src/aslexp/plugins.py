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


def import_modules(modules: str | list[str] | None) -> None:
    """A config section's ``module:`` key (one module or a list), each imported: it registers what the
    section names (a reward error, a planner update); one that cannot be is one line."""
    for module in [modules] if isinstance(modules, str) else modules or []:
        try:
            importlib.import_module(str(module))
        except ImportError as error:
            raise ConfigError(f"module={module}: could not be imported ({error})") from None


def register_function(registry: dict, what: str, name: str, replace: bool = False, built_in: tuple[str, ...] = ()):
    """A decorator that puts its function into ``registry`` under ``name`` (``what`` names the kind in
    the refusals: a built-in name, or a name another module registered, unless ``replace``)."""

    def decorate(function):
        if name in built_in:
            raise ValueError(f"{what} {name!r} is built in")
        known = registry.get(name)
        if known is not None and known is not function and not replace:
            raise ValueError(f"{what} {name!r} is already registered ({known.__module__}); choose another "
                             "name or pass replace=True")
        registry[name] = function
        return function

    return decorate
