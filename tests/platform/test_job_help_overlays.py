"""`aslexp <job> --help` lists exactly the experiment overlays that compose for the job:
the catalogue of conf/experiment/ one per line with its description, and a count of the archived
probes of conf/experiment/archive/, which compose too."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import job_process
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from aslexp import cli

CONF = Path(__file__).resolve().parents[2] / "conf"
JOBS = ("imitate", "recognize", "tune_pd")
ARCHIVE = CONF / "experiment" / "archive"


def _overlays(folder: Path, prefix: str = "") -> list[str]:
    return sorted(prefix + p.stem for p in folder.glob("*.yaml"))


def test_every_overlay_is_listed_for_exactly_one_job():
    listed = [name for job in JOBS for name in cli.experiments_of(job)]
    assert sorted(listed) == _overlays(CONF / "experiment")  # each once, none left out
    archived = [name for job in JOBS for name in cli.experiments_of(job, archived=True)]
    assert sorted(archived) == _overlays(ARCHIVE, "archive/") and archived


def test_the_catalogue_stays_small():
    """The thesis' tables and aslexp's headline settings, about 12; probes go to archive/."""
    # beside the thesis' tables: the letters' and the signs' ceilings (letters_mpc, signs_mpc, standing),
    # one policy for unseen letters (letters_unseen), a residual policy that learns on the standing signs
    # (signs_standing_residual_quiet) and one for signs it never saw (signs_unseen, and its variants that
    # see the tracking error, signs_unseen_tracking_error, stop early, signs_unseen_validated, correct the
    # arms alone, signs_unseen_arms, stop on the thesis' other signs, signs_unseen_arms_thesis_validated,
    # or correct the arms and wrists on a pool whose wrists move, signs_unseen_wrists)
    assert len(_overlays(CONF / "experiment")) <= 24


@pytest.mark.parametrize("job", JOBS)
def test_the_help_lists_the_job_s_catalogue_and_counts_its_archive(job):
    # Each overlay listed here composes for its job and passes the job's config check:
    # tests/platform/test_config_validation.py::test_every_shipped_config_passes composes exactly these.
    if cli.experiments_of(job):
        assert _listed(job) == set(cli.experiments_of(job))
        archived = len(cli.experiments_of(job, archived=True))
        assert f"and {archived} archived probe" in cli.job_help(job) and "experiment=archive/NAME" in cli.job_help(job)
        assert not any(n in cli.job_help(job) for n in cli.experiments_of(job, archived=True))  # a count, not the list


def _catalogue(job: str) -> dict[str, str]:
    """The help's experiments section: name -> description."""
    lines = cli.job_help(job).split("\nexperiments (", 1)[1].split("\n\n", 1)[0].splitlines()[1:]
    return dict(re.match(r"  (\S+)\s+(.*)", ln).groups() for ln in lines if not ln.startswith("  and "))


def _listed(job: str) -> set[str]:
    return set(_catalogue(job))


def test_every_catalogue_overlay_has_a_one_line_description_in_the_help():
    for job in ("imitate", "recognize"):
        for name, description in _catalogue(job).items():
            text = (CONF / "experiment" / f"{name}.yaml").read_text(encoding="utf-8").splitlines()
            assert text[0] == "# @package _global_" and text[1] == f"# {description}", name
            assert 20 < len(description) <= 100 and not description.startswith("Archived"), name


def test_every_archived_overlay_says_what_it_showed_and_the_readme_lists_it_once():
    readme = (ARCHIVE / "README.md").read_text(encoding="utf-8")
    for path in ARCHIVE.glob("*.yaml"):
        text = path.read_text(encoding="utf-8").splitlines()
        assert text[0] == "# @package _global_" and text[1].startswith("# Archived: "), path.name
        assert cli.experiment_description(f"archive/{path.stem}") == text[1][2:]
        assert readme.count(f"| `{path.stem}` | {text[1][len('# Archived: '):]} |") == 1, path.name
    assert readme.count("\n| `") == len(list(ARCHIVE.glob("*.yaml")))


def _composed(name: str, *overrides: str) -> dict:
    with initialize_config_dir(str(CONF), version_base="1.3"):
        cfg = OmegaConf.to_container(compose("imitate", overrides=[f"experiment={name}", *overrides],
                                             return_hydra_config=True), resolve=False)
    for section in ("runtime", "overrides", "job"):  # what names the run, not what it runs
        cfg["hydra"].pop(section)
    return cfg


def test_letters_tracking_written_out_composes_what_it_did_on_the_archived_letters():
    on_letters = _composed("archive/letters", "controller=reference_velocity_tuned", "env=residual_velocity",
                           "env.early_termination.min_reward=null", "ppo.critic_warmup_steps=16384",
                           "ppo.total_steps=98304", "render.frames_every=3")
    assert _composed("letters_tracking") == on_letters


def test_the_residual_headline_written_out_composes_what_the_archived_chain_did():
    chain = _composed("archive/signs_free_residual_anneal_quiet", "ppo.total_steps=327680", "ppo.max_minutes=60")
    assert _composed("signs_free_residual_anneal_quiet_328k") == chain


def test_imitate_help_shows_the_thesis_overlays_and_not_recognition_ones():
    assert {"letters_thesis", "signs_thesis_run1", "signs_thesis_run2", "signs_free_residual"} <= _listed("imitate")
    assert not {"thesis_ch3", "thesis_ch4"} & _listed("imitate")
    assert {"thesis_ch3", "thesis_ch4"} <= _listed("recognize")


def test_an_overlay_is_cut_with_plain_overrides(tmp_path):
    """docs/reference.md: values on the command line replace an overlay's swept lists (no nested quoting)."""
    import sys

    proc = job_process.run([sys.executable, "-m", "aslexp.jobs.imitate", "-m", "experiment=letters_tracking",
                           "motion=A,B", "seed=0", "ppo.total_steps=0", "plots=false", "render.gif=false",
                           "render.mp4=false", "ppo.eval_steps=24",
                           f"hydra.sweep.dir={tmp_path / 'cut'}"],
                          cwd=CONF.parent, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Launching 2 jobs" in proc.stdout + proc.stderr
    jobs = sorted(p.name for p in (tmp_path / "cut").iterdir() if (p / "run.json").is_file())
    assert jobs == ["0", "1"]


def test_the_env_reference_lists_every_env_key_and_its_archived_only_keys_stay_so():
    """docs/reference_env.md: one row per EnvSpec key; the keys it calls "archived probe(s) only" are
    at their defaults in every catalogue overlay (so the table stays true, or fails here)."""
    import dataclasses

    from aslexp.envs.imitation import EnvSpec

    doc = (CONF.parent / "docs" / "reference_env.md").read_text(encoding="utf-8")
    rows = {m.group(1): m.group(2) for m in re.finditer(r"^\| `([\w.]+)` \|(.*)$", doc, re.M)}
    for field in dataclasses.fields(EnvSpec):
        assert field.name in rows or any(k.startswith(field.name + ".") for k in rows), field.name
    archived_only = [k for k, row in rows.items() if "archived probe" in row and " only" in row]
    assert set(archived_only) == {"heading_shaping", "offset_shaping", "residual_base_smoothing",
                                  "residual_base_smoothing_groups"}
    defaults = EnvSpec()
    for name in cli.experiments_of("imitate"):
        env = _composed(name)["env"]
        for key in archived_only:
            assert env.get(key, getattr(defaults, key)) in (getattr(defaults, key), None), (name, key)
