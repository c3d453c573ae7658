"""The command line of the report modules that print one sweep folder's table
(``python -m aslexp.reports.thesis_report FOLDER``): one positional folder, ``--help``, and a folder
that holds no runs of the kind (or does not exist) is one line on stderr, exit 2, as the jobs do."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from aslexp.errors import DataError


def folder_main(summarize: Callable[[Path], dict[str, Any]], module: str, doc: str | None,
                argv: Sequence[str] | None = None) -> int:
    """Print ``summarize(FOLDER)["table"]``; ``doc``: the module's docstring (its first paragraph is the help)."""
    prog = f"python -m {module}"
    parser = argparse.ArgumentParser(prog=prog, description=(doc or "").split("\n\n")[0] or None)
    parser.add_argument("folder", type=Path, help="a sweep folder (hydra.sweep.dir) or a folder of run folders")
    args = parser.parse_args(argv)
    try:
        print(summarize(args.folder)["table"])
    except (FileNotFoundError, NotADirectoryError, DataError) as err:
        print(f"{prog}: {err}", file=sys.stderr)
        return 2
    return 0
