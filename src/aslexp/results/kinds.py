"""The registry of report kinds: a catalogue entry's ``report:`` names one. A kind turns the entry's
run folders into a snapshot's rows (``summarize``) and, where the generic entry does not fit, a
snapshot into the entry's lines on the page (``render``). A new job's results are one module that
registers its kind plus one catalogue entry::

    from aslexp.results.kinds import ReportKind, register_report

    def summarize(entry, folders):        # -> {"rows": [...], "run_dirs": [...], "skipped": {...}, ...}
        ...

    register_report(ReportKind("my_job", summarize, job_defaults=True))

and in ``conf/results.yaml`` an entry with ``report: my_job`` and ``module: my_package.my_results``
(imported to register it; or an entry point of the group ``aslexp.results``). The built-in kinds
register when their modules (:data:`BUILT_IN_MODULES`) are first looked up.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from aslexp.plugins import import_registering_module, load_entry_points, register_function

ENTRY_POINT_GROUP = "aslexp.results"
BUILT_IN_MODULES = ("aslexp.results.imitation", "aslexp.results.recognition", "aslexp.results.retrieval",
                    "aslexp.results.seen_glosses", "aslexp.results.signing")

Summarizer = Callable[[dict[str, Any], list[Path]], dict[str, Any]]
Renderer = Callable[[dict[str, Any], dict[str, Any] | None], list[str]]


@dataclass(frozen=True)
class ReportKind:
    """``summarize(entry, folders)``: the snapshot's rows and what it read (``rows``, ``run_dirs``,
    ``skipped``; optionally ``quantity``, ``row_name``, ``facts``, ``differences``...); ``render(entry,
    snapshot)``: the entry's lines (None: :func:`aslexp.results.render.render_entry`); ``job_defaults``:
    one job run's own table, whose entry may name no overlay (the job's defaults are its setting);
    ``refresh(entry, kept)``: what a kept snapshot (its run folders gone) gains now ({}: nothing),
    said as ``refreshed`` in the list of what happened."""

    name: str
    summarize: Summarizer
    render: Renderer | None = None
    job_defaults: bool = False
    refresh: Callable[[dict[str, Any], dict[str, Any]], dict[str, Any]] | None = None
    refreshed: str = "refreshed"


_KINDS: dict[str, ReportKind] = {}
_built_ins_loaded = False


def register_report(kind: ReportKind, replace: bool = False) -> ReportKind:
    """Register ``kind`` under its name; a name another module registered is refused unless ``replace``."""
    register_function(_KINDS, "report kind", kind.name, replace)(kind)
    return kind


def _load() -> None:
    global _built_ins_loaded
    if not _built_ins_loaded:
        _built_ins_loaded = True
        for module in BUILT_IN_MODULES:
            importlib.import_module(module)
    load_entry_points(ENTRY_POINT_GROUP, "report kind")


def import_kind(name: str, module: str) -> None:
    """Import ``module``, which registers the report kind ``name`` (a catalogue entry's ``module:``)."""
    import_registering_module("report kind", name, module)


def known() -> tuple[str, ...]:
    """The names of every registered report kind."""
    _load()
    return tuple(_KINDS)


def report_kind(name: str) -> ReportKind:
    """The registered kind ``name``; an unknown one is a KeyError naming the known ones."""
    _load()
    if name not in _KINDS:
        raise KeyError(f"unknown report {name!r} (known: {', '.join(sorted(_KINDS))})")
    return _KINDS[name]
