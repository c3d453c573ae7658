"""The command line a newcomer lives in: fast per-job help, one way to pick an
experiment, no test objective in the job list, no import banners."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("torch", "hydra", "optuna", "pybullet", "aslexp.jobs.recognize", "aslexp.jobs.imitate")


@pytest.mark.parametrize("job, own, foreign", [
    ("recognize", {"classifier", "property", "split", "experiment", "classifier_mlp"}, {"motion", "ppo"}),
    ("imitate", {"motion", "ppo", "reward", "experiment", "letters_tracking", "ppo_hand_thesis"}, {"classifier", "split"}),
    ("tune_pd", {"controller", "pd_gains_10"}, {"classifier", "ppo", "experiment"}),
])
def test_job_help_shows_the_job_s_own_groups_without_importing_it(job, own, foreign):
    code = ("import sys, contextlib, io; from aslexp.cli import main; out = io.StringIO()\n"
            f"with contextlib.redirect_stdout(out): main([{job!r}, '--help'])\n"
            f"print(sorted(m for m in {HEAVY!r} if m in sys.modules)); print(out.getvalue())")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded, _, text = proc.stdout.partition("\n")
    assert loaded == "[]", f"--help imported {loaded}"  # what makes Hydra's help take 5-15 s
    words = set(text.replace(",", " ").replace("|", " ").split())
    assert own <= words, own - words
    assert not foreign & words, foreign & words
    assert f"usage: aslexp {job}" in text


def test_the_job_list_hides_the_test_objective_which_still_runs(aslexp, tmp_path):
    listing = aslexp("--help").stdout
    assert "recognize" in listing and "imitate" in listing and "quadratic" not in listing
    ran = aslexp("quadratic", "x=0.5", "y=-1", f"hydra.run.dir={tmp_path / 'q'}")
    assert "objective(x=0.5, y=-1) = -0.04" in ran.stdout


@pytest.mark.parametrize("job, experiment, key", [("recognize", "debug", "num_frames: 32"),
                                                  ("imitate", "archive/letters_quick", "name: fast")])
def test_experiment_without_plus_composes_for_both_jobs(aslexp, job, experiment, key):
    out = aslexp(job, f"experiment={experiment}", "--cfg", "job").stdout
    assert key in out


def test_docs_pick_experiments_with_experiment_not_plus_experiment():
    history = PROJECT_ROOT / "docs" / "archive" / "changelog_by_session.md"  # the old commands, as they were
    for doc in [PROJECT_ROOT / "README.md", *(PROJECT_ROOT / "docs").rglob("*.md"),
                *(PROJECT_ROOT / "conf" / "experiment").glob("*.yaml")]:
        if doc == history:
            continue
        assert "+experiment=" not in doc.read_text(encoding="utf-8"), doc


def test_importing_the_simulator_prints_no_pybullet_banner():
    # Importing the simulator loads no PyBullet (the MuJoCo path runs without it); a world loads it quietly.
    code = ("import sys; from aslexp.sim.world import World; assert 'pybullet' not in sys.modules; "
            "World().close(); assert 'pybullet' in sys.modules; print('ok')")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert proc.stdout.strip() == "ok" and "pybullet build time" not in proc.stderr
    assert "pybullet build time" in subprocess.run(  # the banner is real: it goes without the helper
        [sys.executable, "-c", "import pybullet"], capture_output=True, text=True).stderr


def test_postgres_storage_without_its_driver_names_the_extra():
    from aslexp.tuning.storage import StorageError, open_storage

    with pytest.raises(StorageError) as err:
        open_storage("postgresql+pg8000://u:secret@127.0.0.1:1/db")
    text = str(err.value)
    assert "pip install 'aslexp[postgres]'" in text and "secret" not in text and "\n" not in text


@pytest.mark.parametrize("module", ["thesis_report", "residual_report", "report", "upper_body_report"])
def test_a_report_module_on_a_folder_without_its_runs_is_one_line_and_exit_2(module, tmp_path):
    """`python -m aslexp.reports.X FOLDER` (documented in docs/imitation*.md and BENCHMARKS.md): no
    traceback for a missing argument or a folder without runs; --help says what it takes."""
    def run(*args):
        return subprocess.run([sys.executable, "-m", f"aslexp.reports.{module}", *args], capture_output=True,
                              text=True, timeout=120)

    empty = run(str(tmp_path))
    assert empty.returncode == 2 and empty.stdout == "", empty.stderr
    assert len(empty.stderr.strip().splitlines()) == 1 and str(tmp_path) in empty.stderr, empty.stderr
    missing = run()
    assert missing.returncode == 2 and "Traceback" not in missing.stderr and "folder" in missing.stderr
    assert "usage:" in run("--help").stdout


def test_cfg_with_multirun_shows_the_first_job(aslexp):
    # Hydra refuses -m with --cfg; aslexp shows the multirun's first job and says so
    done = aslexp("imitate", "-m", "motion=A,B", "seed=0,1", "+sweeps=mpc_hand", "--cfg", "job")
    assert "the config of the multirun's first job (motion=A, seed=0)" in done.stderr
    assert "\nseed: 0\n" in done.stdout and "study_name" not in done.stdout and "planner:" in done.stdout


@pytest.mark.parametrize("job, typo, hint", [
    ("imitate", "motoin=A", "did you mean motion?"),
    ("imitate", "ppo.totl_steps=3", "did you mean ppo.total_steps?"),
    ("imitate", "engine=mujuco", "did you mean engine=mujoco?"),
    ("recognize", "classifier=stgnc", "did you mean classifier=stgcn?"),
])
def test_a_typo_gets_a_did_you_mean(aslexp, job, typo, hint):
    # one line, exit 2, the closest key or option of the job's own config
    done = aslexp(job, typo, check=False)
    line = done.stderr.strip().splitlines()[-1]
    assert done.returncode == 2 and hint in line and "Config search path" not in line


def test_a_group_set_to_null_in_a_multirun_names_the_way_that_works(aslexp, tmp_path):
    # Hydra's multirun refuses GROUP=null ("Got NoneType"); the line says to write ~GROUP instead
    done = aslexp("imitate", "-m", "experiment=letters_mpc", "planner=null", f"hydra.sweep.dir={tmp_path}/s",
                  check=False)
    line = done.stderr.strip().splitlines()[-1]
    assert done.returncode == 2, done.stderr[-2000:]
    assert "planner=null cannot be given to a multirun (-m): drop the group with ~planner instead" in line
