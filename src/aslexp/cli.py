"""`aslexp <command> ...`: thin dispatch to the jobs and tools. No logic lives here.

Hydra jobs (any module in aslexp.jobs with a ``main``) take Hydra overrides:

    aslexp recognize property=sign_type classifier=stgcn split=gloss seed=3
    aslexp recognize -m classifier=mlp,gru,stgcn property=sign_type,major_location
    aslexp imitate motion=A

Tools take ordinary flags:

    aslexp data fetch|check --root DIR
    aslexp report RUN_OR_SWEEP_DIR... [--out DIR]     aslexp report --results   (docs/results.md)
    aslexp runs list|diff ...        aslexp sweep status|best|report|dashboard SWEEP_DIR
    aslexp extract VIDEO_OR_DIR... --out DIR

``aslexp <job> --help`` is answered from the config files alone (no job module, torch or Hydra
is imported): the job's own config groups and options, its experiments (the catalogue of
``conf/experiment/``, one line each from the overlay's first comment line, and a count of the
archived probes of ``conf/experiment/archive/``) and sweeps.
"""

from __future__ import annotations

import ast
import importlib
import pkgutil
import sys
from pathlib import Path

import aslexp.jobs
from aslexp.paths import CONF_DIR, SWEEPS_DIR

_TOOLS = {
    "data": ("aslexp.tools.data", "data_main", "fetch or verify the data root"),
    "report": ("aslexp.tools.report", "report_main",
               "runs into tables (recognition: intervals, comparisons); --results: docs/results.md"),
    "runs": ("aslexp.runs.cli", "runs_main", "list and diff run directories"),
    "sweep": ("aslexp.runs.cli", "sweep_main", "status, best trial, plots, dashboard of a sweep"),
    "extract": ("aslexp.pose.extract_cli", "extract_main", "videos -> keypoints (MediaPipe)"),
}
# Jobs that run but are not listed: the test objective of the sweep machinery.
_UNLISTED_JOBS = {"quadratic"}
_CONF = CONF_DIR
_SWEEPS = SWEEPS_DIR


def _jobs() -> list[str]:
    """The job modules: those with a config of their name in conf/."""
    return sorted(
        m.name for m in pkgutil.iter_modules(aslexp.jobs.__path__)
        if not m.name.startswith("_") and (_CONF / f"{m.name}.yaml").is_file()
    )


def _usage() -> str:
    lines = ["usage: aslexp <command> [args]", "", "jobs (Hydra overrides, -m for multirun):"]
    lines += [f"  {name:<9} {_job_summary(name)}" for name in _jobs() if name not in _UNLISTED_JOBS]
    lines += ["", "tools:"]
    lines += [f"  {name:<9} {doc}" for name, (_, _, doc) in _TOOLS.items()]
    lines += ["", "`aslexp <job> --help` shows a job's config groups and options; --debug keeps "
              "tracebacks."]
    return "\n".join(lines)


# --------------------------------------------------------------------------- fast job help


def _docstring(job: str) -> str:
    path = Path(aslexp.jobs.__path__[0]) / f"{job}.py"
    try:
        return ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    except (OSError, SyntaxError):
        return ""


def _job_summary(job: str) -> str:
    first = _docstring(job).strip().splitlines()[:1]
    text = first[0] if first else ""
    return text.split(":", 1)[1].strip() if text.startswith(("`", "``")) and ":" in text else text


def _yaml(path: Path) -> dict:
    import yaml

    try:
        loaded = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError):
        return {}
    return loaded if isinstance(loaded, dict) else {}


def _options(group: str) -> list[str]:
    folder = _CONF / group
    return sorted(p.stem for p in folder.glob("*.yaml")) if folder.is_dir() else []


def _referenced(config: dict, group: str = "experiment", _seen: frozenset = frozenset()) -> set[str]:
    """Groups and top-level keys an overlay touches: its keys, its ``override /env: x`` (-> env),
    the keys its sweeper sweeps, and those of the overlays it builds on: ``name`` (an overlay of
    ``group``) or ``/experiment/archive/name`` (absolute, as the archived overlays name theirs)."""
    keys = {k for k in config if k not in ("defaults", "hydra")}
    params = ((config.get("hydra") or {}).get("sweeper") or {}).get("params") or {}
    keys |= {str(k).lstrip("+~").split(".")[0] for k in params}
    for entry in config.get("defaults") or []:
        if isinstance(entry, dict):
            for key in entry:
                name = str(key).replace("override", "").strip().lstrip("/")
                if name and not name.startswith("hydra"):
                    keys.add(name.split("/")[0])
        elif isinstance(entry, str) and entry != "_self_" and entry not in _seen:
            path = entry[1:] if entry.startswith("/") else f"{group}/{entry}"
            if path.split("/")[0] == group:  # another overlay of the group: its keys are global
                keys |= _referenced(_yaml(_CONF / f"{path}.yaml"), group, _seen | {entry})
            else:  # a config of another group, by its absolute path
                keys.add(path.split("/")[0])
    return keys


def _job_config(job: str, _seen: frozenset = frozenset()) -> tuple[dict, dict[str, str | None]]:
    """A job's config file as Hydra composes its top level: the keys (those of another job's config
    its defaults include first, ``- imitate``) and its groups with their defaults (an ``override
    GROUP: OPTION`` of its own replacing the included one's)."""
    config = _yaml(_CONF / f"{job}.yaml")
    keys: dict = {}
    groups: dict[str, str | None] = {}
    for entry in config.get("defaults") or []:
        if (isinstance(entry, str) and "/" not in entry and entry not in ("_self_", *_seen)
                and (_CONF / f"{entry}.yaml").is_file()):
            included, their_groups = _job_config(entry, _seen | {job})
            keys.update(included)
            groups.update(their_groups)
        elif isinstance(entry, dict):
            for key, value in entry.items():
                name = str(key)
                if name.startswith("override "):
                    name = name[len("override "):].strip()
                    if name in groups:
                        groups[name] = None if value is None else str(value)
                elif not name.startswith("hydra"):
                    groups[name] = None if value is None else str(value)
    keys.update({k: v for k, v in config.items() if k not in ("defaults", "hydra")})
    return keys, groups


def _job_keys(job: str) -> set[str]:
    """A job's config groups and top-level keys."""
    keys, groups = _job_config(job)
    return set(keys) | set(groups)


ARCHIVE = "archive"  # conf/experiment/archive/: the probes behind the catalogue, experiment=archive/NAME


def experiments_of(job: str, archived: bool = False) -> list[str]:
    """The overlays of ``conf/experiment`` written for ``job`` (the catalogue; with ``archived``,
    those of ``conf/experiment/archive``, named ``archive/NAME`` as Hydra selects them): every
    group or key they touch that some job knows is one of this job's, and one at least is this
    job's alone (``seed`` or ``logger`` alone says nothing). Keys no job has (an overlay's own
    ``report:``) are its additions and do not count."""
    jobs = {j: _job_keys(j) for j in _jobs() if j not in _UNLISTED_JOBS}
    known = set().union(*jobs.values())
    shared = set.intersection(*jobs.values())
    if job not in jobs or "experiment" not in jobs[job]:
        return []
    folder, prefix = (_CONF / "experiment" / ARCHIVE, f"{ARCHIVE}/") if archived else (_CONF / "experiment", "")
    mine = []
    for path in sorted(folder.glob("*.yaml")):
        touched = _referenced(_yaml(path)) & known
        if touched <= jobs[job] and touched - shared:
            mine.append(prefix + path.stem)
    return mine


def experiment_description(name: str) -> str:
    """An overlay's one-line description: its first comment line after the ``# @package`` header
    (Hydra reads the header only while the lines are ``# @...``, so it stays first)."""
    try:
        text = (_CONF / "experiment" / f"{name}.yaml").read_text(encoding="utf-8")
    except OSError:
        return ""
    for line in text.splitlines():
        line = line.strip()
        if not line or line.lstrip("#").strip().startswith("@"):
            continue
        return line.lstrip("#").strip() if line.startswith("#") else ""
    return ""


def _catalogue(job: str) -> list[str]:
    """The help's experiments section: the catalogue one per line, the archive as a count."""
    names = experiments_of(job)
    if not names:
        return []
    width = max(len(n) for n in names)
    lines = ["", "experiments (experiment=NAME, conf/experiment/; values on the command line cut a sweep):"]
    lines += [f"  {name:<{width}}  {experiment_description(name)}" for name in names]
    archived = experiments_of(job, archived=True)
    if archived:
        lines.append(f"  and {len(archived)} archived probe{'s' if len(archived) != 1 else ''}: "
                     f"experiment={ARCHIVE}/NAME (one line each: conf/experiment/{ARCHIVE}/README.md)")
    return lines


def _sweeps_of(job: str, job_keys: set[str]) -> list[str]:
    names = []
    for path in sorted(_SWEEPS.glob("*.yaml")):
        text = path.read_text(encoding="utf-8")
        if f"aslexp {job} " in text or f"aslexp.jobs.{job} " in text:
            names.append(path.stem)
        elif "aslexp " not in text and "aslexp.jobs." not in text:
            params = (_yaml(path).get("hydra") or {}).get("sweeper", {}).get("params") or {}
            if params and {str(k).lstrip("+").split(".")[0] for k in params} <= job_keys:
                names.append(path.stem)
    return names


def job_help(job: str) -> str:
    """The help of one job, from its config files: groups, options, experiments, sweeps."""
    config, groups = _job_config(job)
    keys = set(groups) | set(config)
    doc = _docstring(job).strip()
    title = doc.split("\n\n")[0].replace("`", "") if doc else f"aslexp {job}"
    lines = [title, "",
             f"usage: aslexp {job} [GROUP=OPTION ...] [KEY=VALUE ...] [-m] [--cfg job] [--debug]", "",
             "config groups (the default first):"]
    width = max([len(g) for g in groups] + [10])
    for group, default in groups.items():
        options = _options(group)
        if group == "experiment":
            options = [f"one of the {len(experiments_of(job))} experiments below"]
        rest = [o for o in options if o != default]
        head = default if default is not None else "(none)"
        lines.append(f"  {group:<{width}}  {head}" + (f" | {', '.join(rest)}" if rest else ""))
    sweeps = _sweeps_of(job, keys)
    if sweeps:
        lines.append(f"  {'+sweeps':<{width}}  {', '.join(sweeps)}   (Optuna: -m +sweeps=NAME)")
    lines.append(f"  {'hydra/...':<{width}}  hydra/launcher=local|slurm, hydra/sweeper=optuna "
                 "(docs/sweeps.md)")
    lines += _catalogue(job)
    scalars = [f"{k}={_short(v)}" for k, v in config.items() if not isinstance(v, (dict, list))]
    if scalars:
        lines += ["", "keys: " + "  ".join(scalars)]
    lines += ["", f"`aslexp {job} [overrides] --cfg job` prints the composed config; "
              "--hydra-help: Hydra's own flags;", "--debug: tracebacks on errors."]
    return "\n".join(lines)


def _short(value: object, width: int = 40) -> str:
    text = "null" if value is None else str(value).lower() if isinstance(value, bool) else str(value)
    return text if len(text) <= width else text[: width - 1] + "…"


# --------------------------------------------------------------------------- dispatch


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
        if "-h" in rest or "--help" in rest:
            print(job_help(command))
            return 0
        job = importlib.import_module(f"aslexp.jobs.{command}")
        # Hydra reads sys.argv; present the job as its own program.
        sys.argv = [f"aslexp {command}", *rest]
        job.main()
        return 0
    print(f"aslexp: unknown command {command!r}\n\n{_usage()}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
