"""How far the engines agree: the no-learning baselines on each engine configuration, side by side.

    python -m aslexp.measure.engine_agreement [--letters A,B,C,D,E] [--signs 00433,52861,69318,69546]
                                         [--seconds 10] [--out outputs/engine_agreement]

For each letter (the hand, the thesis reward ``hand_thesis``) and each sign (the upper body,
``upper_body_thesis``), every controller is driven by the reference (lookahead 0: the reference as
the PD target; 1: one control step ahead) for ``seconds`` of simulated time from phase 0, on every
column of ``conf/engine_agreement.yaml`` (an engine configuration each: today the thesis' engine, the
batching engine with the thesis engine's joint-speed clamp, and the same without it, so the table shows
what the clamp changes), scored by the same reward code. A row that fell or blew up (diverged) says so
beside its number. Writes ``agreement.json`` and ``agreement.md`` (the table docs/engines.md shows)
with the difference of the two columns the YAML's ``difference`` names, per row.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from aslexp.compose import compose, resolve_group
from aslexp.config_schema import Section, Text, key
from aslexp.data.root import resolve_data_root
from aslexp.envs.assembly import ImitationSetup
from aslexp.envs.baselines import Baseline, no_learning_baselines
from aslexp.errors import ConfigError
from aslexp.reports.report import ended_early

# (body, reward, env, rows): the settings whose baselines the thesis and aslexp report.
HAND_ROWS = [
    ("thesis controller (position, kp 0.22, kd 0.87), 240 Hz", "thesis", {}, "hand_thesis"),
    ("thesis controller, 30 Hz", "thesis", {}, "default"),
    ("reference-velocity PD (tuned), 30 Hz", "reference_velocity_tuned", {}, "default"),
    ("reference-velocity PD (tuned), 240 Hz", "reference_velocity_tuned", {}, "hand_thesis"),
]
UPPER_ROWS = [
    # the authors' code's controller (stable PD everywhere, hands 50 / 0.5): one mode, comparable across engines
    ("authors' code: stable PD, pinned base, 240 Hz", "upper_body_thesis_code", {"base": "pinned"}, "upper_body_thesis"),
    ("authors' code: stable PD, standing (free base), 240 Hz", "upper_body_thesis_code", {"base": "free"}, "upper_body_thesis"),
    ("position control (kp 0.22, kd 0.87), fixed base, 30 Hz", "upper_body", {"base": "fixed"}, "upper_body"),
]


@dataclass(frozen=True)
class Column(Section):
    """One column of the table: its heading and its engine (a ``conf/engine`` name or a section)."""

    SECTION = "engine_agreement.columns"

    heading: str = field(metadata=key(Text()))
    engine: Any = None


@dataclass(frozen=True)
class Agreement(Section):
    """``conf/engine_agreement.yaml``: the columns (key -> :class:`Column`, in order) and the two
    whose difference gets a column of its own (None: no such column)."""

    SECTION = "engine_agreement"

    columns: dict[str, Column] = field(default_factory=dict)
    difference: tuple[str, str] | None = None

    def __post_init__(self) -> None:
        if not self.columns:
            raise ConfigError("columns: expected at least one engine configuration")
        unknown = [name for name in self.difference or () if name not in self.columns]
        if unknown:
            raise ConfigError(f"difference={list(self.difference or ())}: {unknown[0]} is no column; "
                              f"expected two of {', '.join(self.columns)}")


def load_agreement(overrides: list[str] | None = None) -> Agreement:
    """The columns as ``conf/engine_agreement.yaml`` (with Hydra ``overrides``) gives them."""
    return Agreement.parse(compose("engine_agreement", overrides or []))


def measure(kind: str, name: str, seconds: float, data_root: Path, agreement: Agreement) -> list[dict[str, Any]]:
    """Every column's baselines of one letter (``kind`` hand) or sign (upper_body)."""
    if kind == "hand":
        body, reward, rows = resolve_group("body", "hand15"), resolve_group("reward", "hand_thesis"), HAND_ROWS
        motion = data_root / "motions" / "hand" / f"{name}.txt"
    else:
        body, reward = resolve_group("body", "upper_body_thesis"), resolve_group("reward", "upper_body_thesis")
        rows, motion = UPPER_ROWS, data_root / "motions" / "upper_body" / f"{name}.txt"
    out = []
    for label, controller, body_overrides, env_name in rows:
        env = resolve_group("env", env_name)
        row = Baseline.parse({"label": label, "controller": controller, "body": body_overrides})
        measured = {}
        for column, spec in agreement.columns.items():
            setup = ImitationSetup.from_groups(motion, body, None, reward, env, spec.engine, data_root=data_root,
                                               complete=True)
            measured[column] = no_learning_baselines(setup, [row], seconds)
        for runs in zip(*measured.values()):
            by_column = dict(zip(measured, runs))
            entry = {"body": kind, "motion": name, "label": label, "lookahead": runs[0]["lookahead"]}
            for column, run in by_column.items():
                entry[column] = run["reward"]
                if agreement.difference and column == agreement.difference[0]:
                    entry["difference"] = run["reward"] - by_column[agreement.difference[1]]["reward"]
            entry.update({f"{column}_{end}": run[end] for column, run in by_column.items() for end in ("fell", "diverged")})
            out.append(entry)
    return out


def _mark(row: dict[str, Any], engine: str) -> str:
    """A row's number with how its episode ended, if it ended early."""
    ends = ended_early({end: row.get(f"{engine}_{end}") for end in ("diverged", "fell")})
    return f"{row[engine]:.3f}" + (f" ({ends})" if ends else "")


def table(rows: list[dict[str, Any]], agreement: Agreement) -> str:
    headings, difference = [], agreement.difference
    for column, spec in agreement.columns.items():
        headings.append(spec.heading)
        if difference and column == difference[0]:
            headings.append(f"{spec.heading} - {agreement.columns[difference[1]].heading}")
    lines = ["| body | motion | controller | lookahead | " + " | ".join(headings) + " |",
             "|" + "---|" * (4 + len(headings))]
    for r in rows:
        cells = []
        for column in agreement.columns:
            cells.append(_mark(r, column))
            if difference and column == difference[0]:
                cells.append(f"{r['difference']:+.3f}")
        lines.append(f"| {r['body']} | {r['motion']} | {r['label']} | {r['lookahead']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m aslexp.measure.engine_agreement", description=__doc__.split("\n")[0])
    parser.add_argument("--letters", default="A,B,C,D,E")
    parser.add_argument("--signs", default="00433,52861,69318,69546", help="'' for none")
    parser.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per baseline")
    parser.add_argument("--out", default="outputs/engine_agreement")
    parser.add_argument("--data-root", default=None)
    parser.add_argument("overrides", nargs="*", help="overrides of conf/engine_agreement.yaml (the columns), "
                        "e.g. difference=[B,A]")
    args = parser.parse_args(argv)
    agreement = load_agreement(args.overrides)
    data_root = resolve_data_root(args.data_root)
    rows = []
    jobs = [("hand", m) for m in args.letters.split(",") if m] + [("upper_body", m) for m in args.signs.split(",") if m]
    for k, (kind, name) in enumerate(jobs, 1):
        rows += measure(kind, name, args.seconds, data_root, agreement)
        print(f"[{k}/{len(jobs)}] {kind} {name}", file=sys.stderr, flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "agreement.json").write_text(json.dumps(rows, indent=1))
    (out / "agreement.md").write_text(table(rows, agreement))
    print(table(rows, agreement))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
