"""Shared plumbing for the Hydra entry points (the only place, with cli.py, that knows Hydra).

Every job is declared with :func:`job_main` and runs its body through :func:`run_guarded`:

* **A finished run is never rewritten.** :class:`RunGuard`, a Hydra callback that every job
  config lists (``conf/hydra/callbacks/aslexp.yaml``), refuses a run folder that holds a finished
  run in ``on_run_start``, before Hydra writes ``.hydra/`` or opens the job's log there; a plain
  multirun into a folder holding finished runs is refused the same way (the Optuna sweeper
  instead gives every trial a folder of its own).
* **One line per error.** Bad input, a refused run or a crash prints one line on stderr (what,
  where, what to do) and exits non-zero (2: bad input or refused, 1: the job failed, 130/143:
  SIGINT/SIGTERM). ``--debug`` or ``HYDRA_FULL_ERROR=1`` prints the traceback as well; the
  run's ``run.json`` and log always keep it.
* **The run folder tells the truth.** run.json ends as completed, failed (with the error),
  pruned or interrupted (Ctrl-C, SIGTERM, ``scancel``); a job whose objective is not a finite
  number is failed, as the sweep records it. The run folder is printed at start and end.
"""

from __future__ import annotations

import functools
import logging
import math
import os
import sys
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from aslexp.errors import ConfigError, DataError
from aslexp.files import describe_os_error
from aslexp import paths
from aslexp.process import Terminated, sigterm_raises, signals_held
from aslexp.runs.logfmt import install_float_rounding, quiet_log_write_errors
from aslexp.runs.record import (
    RUN_FILE,
    Run,
    RunExistsError,
    claim_new_folder,
    finished_run,
    hold_run_folder,
    refuse_finished_run,
    start_run,
)
from aslexp.seeding import seed_everything  # noqa: F401  (re-exported for the jobs)

CONF_DIR = str(paths.CONF_DIR)  # a clone's conf/, or the copy a wheel carries

log = logging.getLogger("aslexp")

_OUR_SWEEPER = "hydra_plugins.aslexp_optuna_sweeper."
_DEBUG_ENV = "ASLEXP_DEBUG"  # "1": tracebacks on; set for child processes from the first one


# --------------------------------------------------------------------------- stopping cleanly


class JobAbort(BaseException):
    """Stop the job with a one-line message and an exit code, before anything ran.

    A BaseException on purpose: Hydra turns an Exception raised in a callback into a warning
    and carries on (it would then write into the refused folder).
    """

    def __init__(self, message: str, code: int = 2) -> None:
        super().__init__(message)
        self.message = message
        self.code = code


class JobFailed(BaseException):
    """A single run's error, recorded in its run folder, on its way to the one-line report.

    A BaseException so that Hydra does not catch it and print its own report around it.
    """

    def __init__(self, error: BaseException, run_dir: Path | None) -> None:
        super().__init__(str(error))
        self.error = error
        self.run_dir = run_dir


def one_line(error: BaseException) -> str:
    """An exception as one line: type and message, continuation lines joined."""
    text = str(error).strip() or type(error).__name__
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    lines = [ln for ln in lines if not ln.startswith(("full_key:", "object_type=", "reference_type="))]
    text = " ".join(lines).split(" Config search path:")[0]  # Hydra's list of where it looked: noise here
    if isinstance(error, ConfigError):
        return text  # names the key, the value given and what is expected
    name = type(error).__name__
    if text.startswith(_HYDRA_NULL_GROUP):
        # Hydra's multirun parser refuses GROUP=null (a single run takes it)
        given = [a.split("=", 1)[0] for a in sys.argv[1:] if a.endswith("=null") and "." not in a.split("=", 1)[0]]
        group = given[0] if given else "GROUP"
        return f"{group}=null cannot be given to a multirun (-m): drop the group with ~{group} instead"
    if name in ("ConfigCompositionException", "MissingConfigException", "OverrideParseException",
                "ConfigKeyError", "InterpolationResolutionError"):
        return text  # Hydra's own messages already say what is wrong (MissingConfigException is an OSError)
    if isinstance(error, OSError):
        return describe_os_error(error)  # the file it names; "disk full" for ENOSPC
    return f"{name}: {text}"


_HYDRA_NULL_GROUP = "Config group override must be a string or a list. Got NoneType"


def _bad_input(error: BaseException) -> bool:
    """Exit 2: a config value (ConfigError, Hydra's and OmegaConf's errors), an input file that
    does not follow its format (DataError: keypoints, motions, checkpoints) or is missing."""
    return (isinstance(error, (ConfigError, DataError, FileNotFoundError))
            or type(error).__module__.split(".")[0] in ("hydra", "omegaconf")
            or str(error).startswith(_HYDRA_NULL_GROUP))  # Hydra raises a plain ValueError for it


def did_you_mean(message: str, job: str) -> str:
    """"; did you mean X?" for a mistyped key (Hydra: "Could not override 'ppo.totl_steps'") or a
    mistyped option of a group ("Could not find 'engine/mujuco' Available options in 'engine': ..."),
    from the job's own config; "" when nothing is close."""
    import difflib
    import re

    option = re.search(r"Could not find '([\w/.-]+)/([\w.-]+)'\s*Available options in '[\w/.-]+':\s*(.*)$",
                       message)
    if option:
        group, name, available = option[1], option[2], option[3].split()
        close = difflib.get_close_matches(name, available, n=1, cutoff=0.6)
        return f"; did you mean {group}={close[0]}?" if close else ""
    key = re.search(r"Could not override '([\w.]+)'", message) or re.search(r"Key '([\w.]+)' is not in struct", message)
    if not key:
        return ""
    try:
        from hydra import compose, initialize_config_dir
        from hydra.core.global_hydra import GlobalHydra

        GlobalHydra.instance().clear()
        with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
            config = OmegaConf.to_container(compose(job), resolve=False)
    except Exception:  # noqa: BLE001 - a hint only
        return ""

    def keys(node, prefix=""):
        for name, value in (node.items() if isinstance(node, dict) else ()):
            yield prefix + str(name)
            yield from keys(value, f"{prefix}{name}.")

    close = difflib.get_close_matches(key[1], list(keys(config)), n=1, cutoff=0.75)
    return f"; did you mean {close[0]}?" if close else ""


def _debug_requested(argv: list[str]) -> bool:
    if "--debug" in argv:
        return True
    if _DEBUG_ENV in os.environ:  # set by the first aslexp process for its children
        return os.environ[_DEBUG_ENV] == "1"
    return os.environ.get("HYDRA_FULL_ERROR") == "1"


def _exit_for(error: BaseException, prog: str, debug: bool) -> int:
    """Print the one-line report of ``error`` (plus its traceback under --debug); exit code."""
    if isinstance(error, JobAbort):
        print(f"{prog}: {error.message}", file=sys.stderr, flush=True)
        return error.code
    if isinstance(error, KeyboardInterrupt):
        what = "SIGTERM" if isinstance(error, Terminated) else "Ctrl-C"
        note = getattr(error, "aslexp_note", None)
        if debug:
            traceback.print_exception(error)
        print(f"{prog}: interrupted ({what})" + (f": {note}" if note else ""), file=sys.stderr,
              flush=True)
        return 143 if isinstance(error, Terminated) else 130
    run_dir = None
    if isinstance(error, JobFailed):
        error, run_dir = error.error, error.run_dir
    if debug:
        traceback.print_exception(error)
    where = f" (run folder {run_dir})" if run_dir else ""
    hint = "" if debug or run_dir or isinstance(error, ConfigError) else "; --debug shows the traceback"
    print(f"{prog}: {one_line(error)}{did_you_mean(one_line(error), prog.split()[-1])}{where}{hint}",
          file=sys.stderr, flush=True)
    return 2 if _bad_input(error) else 1


def _first_job_of_multirun_cfg(argv: list[str], prog: str) -> list[str]:
    """``-m ... --cfg job`` (Hydra refuses the pair): the config of the multirun's first job, each
    swept override at its first value, said on stderr."""
    args = argv[1:]
    multirun = {"-m", "--multirun"} & set(args)
    if not multirun or not ({"-c", "--cfg"} & set(args)):
        return argv
    from hydra.core.override_parser.overrides_parser import OverridesParser

    words = [a for a in args if a not in multirun]
    overrides = [a for a in words if "=" in a and not a.startswith("-")]
    first = {}
    for override in OverridesParser.create().parse_overrides(overrides):
        if override.is_sweep_override():
            first[override.input_line] = f"{override.get_key_element()}={next(iter(override.sweep_string_iterator()))}"
    if first:
        print(f"{prog}: --cfg with -m: the config of the multirun's first job ({', '.join(first.values())})",
              file=sys.stderr, flush=True)
    return [argv[0], *[first.get(w, w) for w in words]]


def job_main(config_name: str) -> Callable[[Callable[[DictConfig], Any]], Callable[[], Any]]:
    """``@job_main("recognize")``: ``hydra.main`` with aslexp's error handling around it.

    The decorated ``main()`` runs the Hydra app; any error ends the process with one line on
    stderr and a non-zero exit (see the module docstring). ``--debug`` anywhere on the command
    line keeps the tracebacks (it is removed before Hydra parses the overrides).
    """
    import hydra

    def decorate(task: Callable[[DictConfig], Any]) -> Callable[[], Any]:
        hydra_app = hydra.main(version_base="1.3", config_path=CONF_DIR, config_name=config_name)(task)

        @functools.wraps(task)
        def main() -> Any:
            prog = f"aslexp {config_name}"
            debug = _debug_requested(sys.argv[1:])
            sys.argv = [a for i, a in enumerate(sys.argv) if i == 0 or a != "--debug"]
            os.environ[_DEBUG_ENV] = "1" if debug else "0"
            os.environ["HYDRA_FULL_ERROR"] = "1"  # Hydra re-raises; the report is ours
            try:
                sys.argv = _first_job_of_multirun_cfg(sys.argv, prog)
                return hydra_app()
            except SystemExit:
                raise
            except BaseException as error:  # noqa: BLE001 - every error becomes one line
                sys.exit(_exit_for(error, prog, debug))

        return main

    return decorate


# --------------------------------------------------------------------------- the run guard


def _resolved(config: DictConfig, key: str) -> str | None:
    HydraConfig.instance().set_config(config)  # ${hydra:...} in paths needs it
    value = OmegaConf.select(config, key)
    return None if value is None else str(value)


# Keys a resume in place must share with the run it continues (Hydra rewrites the folder's
# config before the job reads it, so this is checked here, before Hydra writes).
RESUME_IDENTITY = ("motion.name", "body.name", "seed")


def _timestamped(config: DictConfig, key: str) -> bool:
    """Whether ``key`` is a default, time-stamped folder name (``${now:...}`` in it)."""
    node, _, leaf = key.rpartition(".")
    raw = OmegaConf.to_container(OmegaConf.select(config, node), resolve=False)
    return isinstance(raw, dict) and "${now:" in str(raw.get(leaf, ""))


class RunGuard(Callback):
    """Claim the run folder before Hydra writes anything into it.

    * A time-stamped default folder is created exclusively: a job started in the same second
      with the same name (a Slurm array, two terminals) gets ``<name>_2``.
    * A folder holding a finished run is refused (``overwrite=true`` replaces it).
    * The folder's run lock is held for the whole job: a second job into it (two resumes of one
      run, two array tasks given one ``hydra.run.dir``) is refused while the first lives.
    * An unfinished run's checkpoint is never overwritten by a fresh start; a resume in place
      must continue the same motion, body and seed.
    """

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        from omegaconf import open_dict, read_write

        run_dir = _resolved(config, "hydra.run.dir")
        if run_dir is None:
            return
        overwrite = bool(OmegaConf.select(config, "overwrite", default=False))
        try:
            if _timestamped(config, "hydra.run.dir"):
                claimed = claim_new_folder(run_dir)
                if str(claimed) != run_dir:
                    with read_write(config.hydra.run), open_dict(config.hydra.run):
                        config.hydra.run.dir = str(claimed)
                hold_run_folder(claimed)
                return
            if not overwrite:
                refuse_finished_run(run_dir)
            hold_run_folder(run_dir)
            if not overwrite:
                _refuse_unfinished_restart(config, Path(run_dir))
        except RunExistsError as err:
            raise JobAbort(str(err)) from None
        except OSError as err:  # Hydra would turn an Exception here into a warning and go on
            raise JobAbort(f"cannot claim the run folder {run_dir}: {err}", code=1) from None

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        target = str(OmegaConf.select(config, "hydra.sweeper._target_", default="") or "")
        if target.startswith(_OUR_SWEEPER):
            return  # the Optuna sweeper resumes in its folder and never reuses a trial folder
        if OmegaConf.select(config, "overwrite", default=False):
            return
        sweep_dir = _resolved(config, "hydra.sweep.dir")
        if sweep_dir is None or not Path(sweep_dir).is_dir():
            return
        finished = [p.parent for p in sorted(Path(sweep_dir).rglob(RUN_FILE)) if finished_run(p.parent)]
        if finished:
            raise JobAbort(
                f"{sweep_dir} holds {len(finished)} finished run(s) of an earlier multirun (e.g. "
                f"{finished[0]}); nothing was changed: choose another hydra.sweep.dir (the default "
                "has the date and time), or add overwrite=true to run into it again"
            )
        try:  # two plain multiruns into one folder would run job 0 twice into <dir>/0
            hold_run_folder(sweep_dir)
        except RunExistsError as err:
            raise JobAbort(str(err)) from None


def _refuse_unfinished_restart(config: DictConfig, folder: Path) -> None:
    """Before Hydra rewrites an unfinished run's folder: a fresh start there would overwrite its
    checkpoint; a resume in place must continue the same run (RESUME_IDENTITY)."""
    checkpoint = folder / "checkpoints" / "last.pt"
    resume = OmegaConf.select(config, "resume", default=None)
    if resume:
        target = Path(str(resume)).resolve()
        if target not in (folder.resolve(), checkpoint.resolve()):
            return  # resumed from another folder: the job checks that folder's config
        saved = folder / ".hydra" / "config.yaml"
        if not saved.is_file():
            return
        theirs = OmegaConf.load(saved)
        for key in RESUME_IDENTITY:
            mine, old = OmegaConf.select(config, key), OmegaConf.select(theirs, key)
            if mine is not None and old is not None and str(mine) != str(old):
                raise JobAbort(f"resume in place: {saved}: {key} is {old!r}, this command asks for "
                               f"{mine!r}; nothing was changed: resume with the run's own {key}, or "
                               "start the new one in another hydra.run.dir")
        return
    if checkpoint.is_file():
        raise JobAbort(f"{folder} holds an unfinished run's checkpoint {checkpoint}; nothing was "
                       f"changed: add resume={folder} to continue it, or overwrite=true to start over")


# --------------------------------------------------------------------------- inside the job


def run_dir() -> Path:
    """This job's output directory (Hydra's runtime.output_dir)."""
    return Path(HydraConfig.get().runtime.output_dir)


def to_dict(cfg: DictConfig | Any) -> Any:
    """Plain Python containers for the layers below Hydra."""
    if isinstance(cfg, DictConfig):
        return OmegaConf.to_container(cfg, resolve=True)
    return cfg


def begin(job: str, cfg: DictConfig) -> Run:
    """Start the run record in the Hydra output dir (refuses to overwrite a finished run)."""
    import shlex

    overrides = list(HydraConfig.get().overrides.task)
    extra = {
        # The command that re-runs exactly this job (in a multirun: this one job, not the sweep).
        "command": shlex.join(["aslexp", job, *overrides]),
        "argv": list(sys.argv),
        "overrides": overrides,
    }
    seed = cfg.get("seed")
    return start_run(run_dir(), job, seed=seed, overwrite=bool(cfg.get("overwrite", False)), extra=extra)


def in_multirun() -> bool:
    from hydra.types import RunMode

    return HydraConfig.get().mode == RunMode.MULTIRUN


def _log_to_files_only(message: str) -> None:
    """Write ``message`` to the job's log file(s) only (the console gets the one-line report)."""
    record = log.makeRecord(log.name, logging.ERROR, __file__, 0, message, None, None)
    for handler in logging.getLogger().handlers:
        if isinstance(handler, logging.FileHandler):
            handler.handle(record)


def run_guarded(job: str, cfg: DictConfig, body: Callable[[Run], float | None]) -> float | None:
    """Run ``body(run) -> float`` inside a run record and return its objective (None: a run that
    measures and has no objective, e.g. ``aslexp imitate ppo.total_steps=0``).

    run.json ends as: completed; failed (an exception, or an objective that is not a finite
    number), with the error's one line and its traceback; pruned (optuna.TrialPruned); or
    interrupted (Ctrl-C, SIGTERM). In a multirun, unless ``fail_fast``, a failed job returns NaN
    so that one bad job never ends the sweep (the sweeper reads the real error from run.json).
    In a single run the error ends the process with one line (see :func:`job_main`).
    """
    import optuna

    install_float_rounding()
    quiet_log_write_errors()
    multirun = in_multirun()
    try:
        run = begin(job, cfg)
    except RunExistsError as err:
        if multirun:
            raise
        raise JobAbort(str(err)) from None
    log.info("%s: run folder %s", job, run.dir)
    try:
        with sigterm_raises():
            value = body(run)
        value = None if value is None else float(value)
    except optuna.TrialPruned as exc:
        run.finish("pruned", str(exc))
        log.info("%s pruned: run folder %s", job, run.dir)
        raise
    except KeyboardInterrupt as exc:
        with signals_held():
            run.finish("interrupted", f"interrupted ({'SIGTERM' if isinstance(exc, Terminated) else 'Ctrl-C'})")
        exc.aslexp_note = f"run folder {run.dir} recorded as interrupted"  # type: ignore[attr-defined]
        raise
    except Exception as exc:  # noqa: BLE001 - recorded, then reported or turned into NaN
        trace = "".join(traceback.format_exception(exc))
        run.finish("failed", one_line(exc), trace)
        _log_to_files_only(f"{job} failed:\n{trace}")
        if multirun and not cfg.get("fail_fast", False):
            log.error("%s failed (%s); recorded in %s/run.json, the sweep goes on", job,
                      one_line(exc), run.dir)
            return float("nan")
        if multirun:
            raise
        raise JobFailed(exc, run.dir) from exc
    except BaseException as exc:  # SystemExit and the like: the run did not finish
        run.finish("failed", one_line(exc))
        raise
    if value is None or math.isfinite(value):
        run.finish("completed")
        log.info("%s completed: run folder %s", job, run.dir)
        return value
    error = f"the objective is {value}, not a finite number"
    run.finish("failed", error)
    if multirun:
        log.error("%s failed (%s): run folder %s", job, error, run.dir)
        return value
    raise JobFailed(ValueError(error), run.dir)
