"""The sign experiment's summary (thesis table 6.7): per sign, learned reward beside the baselines
and the thesis' own trained policies.

    python -m aslexp.rl.upper_body_report outputs/imitate-multirun/<sweep>

Reuses :func:`aslexp.rl.report.summarize_letters` (mean/std curves per motion, any motion names)
and adds the thesis column; writes ``signs_table.{md,csv}`` beside ``letters_curves.png``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from aslexp.rl.report import summarize_letters, write_table

# Thesis table 6.7, run 2: mean reward of the trained policies (multiplicative reward).
THESIS_TABLE_6_7 = {"00433": 0.868, "52861": 0.853, "69318": 0.745, "69546": 0.842}
GLOSSES = {"00433": "above", "52861": "snow", "69318": "father", "69546": "yes"}


def summarize_signs(sweep_dir: str | Path, out_dir: str | Path | None = None) -> dict[str, Any]:
    """Table of the sign runs under ``sweep_dir`` with the thesis' table 6.7 beside them."""
    out_dir = Path(out_dir or sweep_dir)
    summary = summarize_letters(sweep_dir, out_dir, targets=THESIS_TABLE_6_7)  # + time to the thesis' reward
    rows = []
    for row in summary["rows"]:
        motion = str(row["motion"])
        thesis = THESIS_TABLE_6_7.get(motion)
        rows.append({"sign": f"{motion} ({GLOSSES.get(motion, '?')})", "thesis_table_6_7": thesis,
                     **{k.replace("_target", "_thesis"): v for k, v in row.items() if k not in ("motion", "target")}})
    table = write_table(rows, out_dir, "signs_table")
    return {"rows": rows, "table": table}


if __name__ == "__main__":
    import sys

    print(summarize_signs(sys.argv[1])["table"])
