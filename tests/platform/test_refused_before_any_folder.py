"""Slips that used to run (or write a folder first) are refused at the edge: a name with a path in
it (``classifier.name=../../x`` put the run folder outside ``outputs/``), an unknown classifier
(refused after its run folder, exit 1), a negative or infinite PD gain, a control rate of 0.001 Hz
(minutes of silent simulation). Each is one line naming the key, the value and what is expected,
exit 2, and nothing written. The real CLI in a subprocess; no job gets as far as any work."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
from platform_helpers import error_lines

import job_process
from aslexp.recognition.registry import BUILT_IN

PROJECT_ROOT = Path(__file__).resolve().parents[2]
CONF = PROJECT_ROOT / "conf"


def _aslexp_in(cwd: Path, *args: str):
    """``aslexp ARGS`` started in ``cwd``: the default, time-stamped run folder lands under ``cwd/outputs``."""
    env = {**os.environ, "ASLEXP_DATA_ROOT": str(PROJECT_ROOT.parent / "shared" / "data"),
           "ASLEXP_CACHE_DIR": str(cwd / "cache"), "MPLBACKEND": "Agg"}
    return job_process.run([sys.executable, "-m", "aslexp.cli", *args], cwd=cwd, env=env,
                           capture_output=True, text=True, timeout=120)


def _everything_under(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.mark.parametrize("args, key, value, folder_key", [
    (("recognize", "classifier.name=../../../x"), "classifier.name", "../../../x", "hydra.run.dir"),
    (("recognize", "split.name=a/b"), "split.name", "a/b", "hydra.run.dir"),
    (("imitate", "motion.name=../../../x"), "motion.name", "../../../x", "hydra.run.dir"),
    (("recognize", "-m", "classifier.name=logreg,../../../x"), "classifier.name", "../../../x",
     "hydra.sweep.subdir"),
])
def test_a_name_with_a_path_in_it_is_refused_before_any_folder(tmp_path, args, key, value, folder_key):
    cwd = tmp_path / "a" / "b" / "c"  # deep enough that ../../../x would have left outputs/ (and cwd)
    cwd.mkdir(parents=True)
    proc = _aslexp_in(cwd, *args)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert error_lines(proc.stderr) == [
        f"aslexp {args[0]}: {key}={value}: expected a name without '/' or '\\' (it is part of the run "
        f"folder's name, {folder_key})"]
    assert _everything_under(tmp_path) == ["a", "a/b", "a/b/c"]  # no outputs/, no x anywhere


def test_an_unknown_classifier_is_refused_before_its_run_folder_listing_the_known_ones(tmp_path):
    cwd = tmp_path / "work"
    cwd.mkdir()
    proc = _aslexp_in(cwd, "recognize", "classifier.name=nosuch")
    assert proc.returncode == 2, proc.stderr[-2000:]
    [line] = error_lines(proc.stderr)
    assert line == ("aslexp recognize: classifier.name=nosuch: unknown classifier; expected one of "
                    f"{', '.join(BUILT_IN)} (or a classifier.module that registers it)")
    assert _everything_under(cwd) == []  # no run folder, no dataset built
    # The other jobs that train a classifier refuse it the same way.
    other = _aslexp_in(cwd, "retrieve", "classifier.name=nosuch")
    assert other.returncode == 2 and error_lines(other.stderr)[0].startswith(
        "aslexp retrieve: classifier.name=nosuch: unknown classifier; expected one of majority, ")
    assert _everything_under(cwd) == []


def test_every_shipped_controller_env_and_body_passes_the_ranges():
    """Every conf/controller and conf/env file read alone, every body with a motion of its width,
    and every imitate and tune_pd overlay assembled as the job's edge check assembles it."""
    from hydra import compose, initialize_config_dir

    from aslexp import cli
    from aslexp.compose import group
    from aslexp.envs.spec import EnvSpec
    from aslexp.jobs.validation import check_controller_and_env, check_imitation_setup, swept_values
    from aslexp.sim.pd import ControllerSpec

    def stems(name: str) -> list[str]:
        return sorted(p.stem for p in (CONF / name).glob("*.yaml"))

    for name in stems("controller"):
        ControllerSpec.parse(group("controller", name))
    for name in stems("env"):
        EnvSpec.parse(group("env", name))
    motion_of = {"final_hand": "A", "hand15": "A", "upper_body": "'00433'", "upper_body_thesis": "'00433'"}
    # upper_body_humanoid (PyBullet's humanoid, 43 values a frame) has no shipped motion: read alone.
    assert set(motion_of) | {"upper_body_humanoid"} == set(stems("body"))
    assembled = 0
    with initialize_config_dir(str(CONF), version_base="1.3"):
        check_controller_and_env(compose("imitate", overrides=["body=upper_body_humanoid"]))
        for body, motion in motion_of.items():
            check_imitation_setup(compose("imitate", overrides=[f"body={body}", f"motion={motion}"]))
            assembled += 1
        overlays = [(job, experiment) for job in ("imitate", "tune_pd")
                    for experiment in cli.experiments_of(job) + cli.experiments_of(job, archived=True)]
        for job, experiment in overlays:
            overrides = [f"experiment={experiment}"]
            plain = compose(job, overrides=overrides, return_hydra_config=True)
            swept = swept_values(plain)
            if "motion" in swept:  # a sweep over motions: its first (the job's default is a letter)
                overrides.append(f"motion='{swept['motion'][0]}'")
            elif job == "imitate":  # one motion given on the command line: one of the body's width
                overrides.append(f"motion={motion_of[plain.body.name]}")
            cfg = compose(job, overrides=overrides)
            (check_imitation_setup if job == "imitate" else check_controller_and_env)(cfg)
            assembled += 1
    assert assembled == len(motion_of) + len(overlays) and len(overlays) >= 25
