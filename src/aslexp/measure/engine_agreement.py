"""How far the engines agree: the no-learning baselines in PyBullet and in MuJoCo, side by side.

    python -m aslexp.measure.engine_agreement [--letters A,B,C,D,E] [--signs 00433,52861,69318,69546]
                                         [--seconds 10] [--out outputs/engine_agreement]

For each letter (the hand, the thesis reward ``hand_thesis``) and each sign (the upper body,
``upper_body_thesis``), every controller is driven by the reference (lookahead 0: the reference as
the PD target; 1: one control step ahead) for ``seconds`` of simulated time from phase 0, in both
engines, scored by the same reward code. MuJoCo runs with PyBullet's joint-speed clamp (100 rad/s,
``engine.joint_speed_limit``, the default) and, in one more column, without it, so the table shows
what the clamp changes. A row that fell or blew up (diverged) says so beside its number. Writes
``agreement.json`` and ``agreement.md`` (the table docs/engines.md shows) with the difference
MuJoCo - PyBullet per row.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from aslexp.data.root import resolve_data_root
from aslexp.envs.assembly import ImitationSetup
from aslexp.envs.baselines import Baseline, no_learning_baselines
from aslexp.compose import resolve_group
from aslexp.reports.report import ended_early

# (body, reward, env, rows): the settings whose baselines the thesis and aslexp report.
HAND_ROWS = [
    ("thesis controller (position, kp 0.22, kd 0.87), 240 Hz", "thesis", {}, "hand_thesis"),
    ("thesis controller, 30 Hz", "thesis", {}, "default"),
    ("reference-velocity PD (tuned), 30 Hz", "reference_velocity_tuned", {}, "default"),
    ("reference-velocity PD (tuned), 240 Hz", "reference_velocity_tuned", {}, "hand_thesis"),
]
# MuJoCo as configured (PyBullet's clamp reproduced) and MuJoCo's own semantics (no clamp).
ENGINES = {"pybullet": "pybullet", "mujoco": {"name": "mujoco"},
           "mujoco_unclamped": {"name": "mujoco", "joint_speed_limit": None}}
UPPER_ROWS = [
    # the authors' code's controller (stable PD everywhere, hands 50 / 0.5): one mode, comparable across engines
    ("authors' code: stable PD, pinned base, 240 Hz", "upper_body_thesis_code", {"base": "pinned"}, "upper_body_thesis"),
    ("authors' code: stable PD, standing (free base), 240 Hz", "upper_body_thesis_code", {"base": "free"}, "upper_body_thesis"),
    ("position control (kp 0.22, kd 0.87), fixed base, 30 Hz", "upper_body", {"base": "fixed"}, "upper_body"),
]


def measure(kind: str, name: str, seconds: float, data_root: Path) -> list[dict[str, Any]]:
    """Both engines' baselines of one letter (``kind`` hand) or sign (upper_body)."""
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
        for engine, config in ENGINES.items():
            setup = ImitationSetup.from_groups(motion, body, None, reward, env, config, data_root=data_root,
                                               complete=True)
            measured[engine] = no_learning_baselines(setup, [row], seconds)
        for pb, mj, free in zip(measured["pybullet"], measured["mujoco"], measured["mujoco_unclamped"]):
            out.append({"body": kind, "motion": name, "label": label, "lookahead": pb["lookahead"],
                        "pybullet": pb["reward"], "mujoco": mj["reward"], "difference": mj["reward"] - pb["reward"],
                        "mujoco_unclamped": free["reward"],
                        **{f"{engine}_{end}": run[end] for engine, run in
                           (("pybullet", pb), ("mujoco", mj), ("mujoco_unclamped", free)) for end in ("fell", "diverged")}})
    return out


def _mark(row: dict[str, Any], engine: str) -> str:
    """A row's number with how its episode ended, if it ended early."""
    ends = ended_early({end: row.get(f"{engine}_{end}") for end in ("diverged", "fell")})
    return f"{row[engine]:.3f}" + (f" ({ends})" if ends else "")


def table(rows: list[dict[str, Any]]) -> str:
    lines = ["| body | motion | controller | lookahead | PyBullet | MuJoCo | MuJoCo - PyBullet | MuJoCo, no speed clamp |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['body']} | {r['motion']} | {r['label']} | {r['lookahead']} | {_mark(r, 'pybullet')} | "
                     f"{_mark(r, 'mujoco')} | {r['difference']:+.3f} | {_mark(r, 'mujoco_unclamped')} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m aslexp.measure.engine_agreement", description=__doc__.split("\n")[0])
    parser.add_argument("--letters", default="A,B,C,D,E")
    parser.add_argument("--signs", default="00433,52861,69318,69546", help="'' for none")
    parser.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per baseline")
    parser.add_argument("--out", default="outputs/engine_agreement")
    parser.add_argument("--data-root", default=None)
    args = parser.parse_args(argv)
    data_root = resolve_data_root(args.data_root)
    rows = []
    jobs = [("hand", m) for m in args.letters.split(",") if m] + [("upper_body", m) for m in args.signs.split(",") if m]
    for k, (kind, name) in enumerate(jobs, 1):
        rows += measure(kind, name, args.seconds, data_root)
        print(f"[{k}/{len(jobs)}] {kind} {name}", file=sys.stderr, flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "agreement.json").write_text(json.dumps(rows, indent=1))
    (out / "agreement.md").write_text(table(rows))
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
