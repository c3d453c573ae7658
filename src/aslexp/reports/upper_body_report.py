"""The sign experiment's summary: per sign, the learned reward beside the no-learning baselines
and thesis Table 6.7 (a like-for-like comparison needs the thesis' reward, controller and rate:
``experiment=signs_thesis_run1|run2`` and :mod:`aslexp.reports.thesis_report`).

    python -m aslexp.reports.upper_body_report outputs/imitate-multirun/<sweep>

Reuses :func:`aslexp.reports.report.summarize_letters` (last and best evaluations, every baseline, curves)
and adds the thesis column; writes ``signs_table.{md,csv}`` beside ``letters_curves.png``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from aslexp.reports.report import summarize_letters, write_table
from aslexp.reports.thesis_report import GLOSSES, THESIS_TABLE_6_7


def summarize_signs(sweep_dir: str | Path, out_dir: str | Path | None = None) -> dict[str, Any]:
    """Table of the sign runs under ``sweep_dir`` with thesis Table 6.7 (Run 2) beside them."""
    out_dir = Path(out_dir or sweep_dir)
    targets = {sign: values[2] for sign, values in THESIS_TABLE_6_7.items()}
    summary = summarize_letters(sweep_dir, out_dir, targets=targets)  # + time to the thesis' reward
    rows = []
    for row in summary["rows"]:
        motion = str(row["motion"])
        rows.append({"sign": f"{motion} ({GLOSSES.get(motion, '?')})", "thesis_table_6_7_run2": targets.get(motion),
                     **{k.replace("_target", "_thesis"): v for k, v in row.items() if k not in ("motion", "target")}})
    table = write_table(rows, out_dir, "signs_table")
    return {"rows": rows, "table": table}


if __name__ == "__main__":  # python -m aslexp.reports.upper_body_report FOLDER
    from aslexp.reports.folder_main import folder_main

    raise SystemExit(folder_main(summarize_signs, __spec__.name, __doc__))
