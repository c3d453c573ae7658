"""`aslexp <job> --help` lists exactly the experiment overlays that compose for the job (issue 27.4)."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from aslexp import cli

CONF = Path(__file__).resolve().parents[2] / "conf"
JOBS = ("imitate", "recognize", "tune_pd")


def test_every_overlay_is_listed_for_exactly_one_job():
    overlays = sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))
    listed = [name for job in JOBS for name in cli.experiments_of(job)]
    assert sorted(listed) == overlays  # each once, none left out


@pytest.mark.parametrize("job", JOBS)
def test_every_overlay_a_job_lists_composes_for_it(job):
    with initialize_config_dir(str(CONF), version_base="1.3"):
        for name in cli.experiments_of(job):
            cfg = compose(job, overrides=[f"experiment={name}"])
            assert cfg is not None, name
    if cli.experiments_of(job):
        assert _listed(job) == set(cli.experiments_of(job))


def _listed(job: str) -> set[str]:
    line = next(ln for ln in cli.job_help(job).splitlines() if ln.strip().startswith("experiment"))
    return {name.strip() for name in line.split(None, 1)[1].replace("|", ",").split(",")} - {"(none)"}


def test_imitate_help_shows_the_thesis_overlays_and_not_recognition_ones():
    assert {"letters_thesis", "signs_thesis_run1", "signs_thesis_run2", "signs_free_residual"} <= _listed("imitate")
    assert not {"thesis_ch3", "thesis_ch4"} & _listed("imitate")
    assert {"thesis_ch3", "thesis_ch4"} <= _listed("recognize")


def test_an_overlay_is_cut_with_plain_overrides(tmp_path):
    """README: values on the command line replace an overlay's swept lists (no nested quoting)."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "aslexp.jobs.imitate", "-m", "experiment=letters_tracking",
                           "motion=A,B", "seed=0", "ppo.total_steps=0", "plots=false", "render.gif=false",
                           "render.mp4=false", "ppo.eval_steps=24",
                           f"hydra.sweep.dir={tmp_path / 'cut'}"],
                          cwd=CONF.parent, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Launching 2 jobs" in proc.stdout + proc.stderr
    jobs = sorted(p.name for p in (tmp_path / "cut").iterdir() if (p / "run.json").is_file())
    assert jobs == ["0", "1"]
