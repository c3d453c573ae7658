"""`aslexp <command> ...`: thin dispatch to the jobs and tools. No logic lives here.

Hydra jobs (any module in aslexp.jobs with a ``main``) take Hydra overrides:

    aslexp recognize property=sign_type classifier=stgcn split=gloss seed=3
    aslexp recognize -m classifier=mlp,gru,stgcn property=sign_type,major_location
    aslexp imitate motion=A

Tools take ordinary flags:

    aslexp data fetch|check --root DIR
    aslexp report RUN_OR_SWEEP_DIR... [--out DIR]
    aslexp runs list|diff ...        aslexp sweep status|best|report|dashboard SWEEP_DIR
    aslexp extract VIDEO_OR_DIR... --out DIR
"""

from __future__ import annotations

import importlib
import pkgutil
import sys

import aslexp.jobs

_TOOLS = {
    "data": ("aslexp.tools.data", "data_main", "fetch or verify the data root"),
    "report": ("aslexp.tools.report", "report_main", "collect recognition runs into tables"),
    "runs": ("aslexp.runs.cli", "runs_main", "list and diff run directories"),
    "sweep": ("aslexp.runs.cli", "sweep_main", "status, best trial, plots, dashboard of a sweep"),
    "extract": ("aslexp.pose.extract_cli", "extract_main", "videos -> keypoints (MediaPipe)"),
}


def _jobs() -> list[str]:
    return sorted(
        m.name for m in pkgutil.iter_modules(aslexp.jobs.__path__) if not m.name.startswith("_")
    )


def _usage() -> str:
    lines = ["usage: aslexp <command> [args]", "", "jobs (Hydra overrides, -m for multirun):"]
    lines += [f"  {name}" for name in _jobs()]
    lines += ["", "tools:"]
    lines += [f"  {name:<9} {doc}" for name, (_, _, doc) in _TOOLS.items()]
    lines += ["", "`aslexp <job> --help` shows a job's config groups and options."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(_usage())
        return 0
    command, rest = argv[0], argv[1:]
    if command in _TOOLS:
        module_name, func_name, _ = _TOOLS[command]
        func = getattr(importlib.import_module(module_name), func_name)
        return int(func(rest) or 0)
    if command in _jobs():
        job = importlib.import_module(f"aslexp.jobs.{command}")
        # Hydra reads sys.argv; present the job as its own program.
        sys.argv = [f"aslexp {command}", *rest]
        job.main()
        return 0
    print(f"aslexp: unknown command {command!r}\n\n{_usage()}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
