"""A body brings its own controller, reward and env: ``body=upper_body`` alone runs
the upper body's groups, not the hand's; a group named on the command line or by an overlay wins."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
import job_process
from hydra import compose, initialize_config_dir

from aslexp import paths

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data"
GROUPS = ("body", "controller", "reward", "env")


def choices(*overrides: str, job: str = "imitate") -> dict[str, str]:
    with initialize_config_dir(config_dir=str(paths.CONF_DIR), version_base="1.3"):
        cfg = compose(job, overrides=list(overrides), return_hydra_config=True)
    return {group: cfg.hydra.runtime.choices[group] for group in GROUPS}


@pytest.mark.parametrize("overrides, expected", [
    ([], ("hand15", "thesis", "deepmimic", "residual")),
    (["body=final_hand"], ("final_hand", "thesis", "deepmimic", "residual")),
    (["body=upper_body"], ("upper_body", "upper_body", "upper_body_thesis", "upper_body")),
    (["body=upper_body_thesis"], ("upper_body_thesis", "upper_body", "upper_body_thesis", "upper_body")),
    (["body=upper_body", "env=upper_body_thesis"], ("upper_body", "upper_body", "upper_body_thesis", "upper_body_thesis")),
    (["experiment=signs_thesis_run1"], ("upper_body", "upper_body_thesis", "upper_body_table6_4_run3", "upper_body_thesis")),
    (["experiment=letters_tracking"], ("hand15", "reference_velocity_tuned", "deepmimic", "residual_velocity")),
])
def test_a_body_brings_its_groups_and_a_named_group_wins(overrides, expected):
    assert choices(*overrides) == dict(zip(GROUPS, expected))


def test_the_pd_tuning_job_takes_the_body_s_groups_too():
    assert choices("body=upper_body", job="tune_pd")["controller"] == "upper_body"


def test_the_python_setup_reads_the_same_body_file():
    from aslexp.envs.assembly import ImitationSetup
    from aslexp.compose import body_groups
    from aslexp.envs.upper_body import UPPER_BODY_DEFAULTS

    assert body_groups("upper_body_thesis") == {"controller": "upper_body", "reward": "upper_body_thesis",
                                                "env": "upper_body"}
    assert UPPER_BODY_DEFAULTS == {"body": "upper_body"}  # the body file brings the rest
    setup = ImitationSetup.from_groups("motions/upper_body/00433.txt", body="upper_body", data_root=DATA)
    named = ImitationSetup.from_groups("motions/upper_body/00433.txt", body="upper_body", controller="upper_body",
                                       reward="upper_body_thesis", env="upper_body", data_root=DATA)
    assert setup.groups == named.groups


def test_an_upper_body_run_from_body_alone_scores_its_own_body_s_baselines(tmp_path):
    """The documented whole-sign command (docs/howto_imitate.md) on a sign given by file: its
    baselines are the upper body's (controller, reward, env), measured in-process with them named."""
    from aslexp.envs.assembly import ImitationSetup
    from aslexp.envs.imitation import ImitationEnv
    from aslexp.rl.evaluate import baselines

    motion = DATA / "motions" / "upper_body" / "00433.txt"
    run = tmp_path / "run"
    proc = job_process.run([sys.executable, "-m", "aslexp.jobs.imitate", f"motion.file={motion}", "body=upper_body",
                           "ppo.total_steps=0", "ppo.eval_steps=12", "ppo.eval_phases=[0.0]", "plots=false",
                           "render.gif=false", "render.mp4=false", f"hydra.run.dir={run}"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    measured = json.loads((run / "metrics.json").read_text())["baselines"]
    setup = ImitationSetup.from_groups(motion, body="upper_body", controller="upper_body", reward="upper_body_thesis",
                                       env={"early_termination": {"min_reward": None}}, data_root=DATA,
                                       defaults={"env": "upper_body"})
    env = ImitationEnv.from_setup(setup)
    try:
        expected = baselines(env, 12, (0.0,))
    finally:
        env.close()
    assert measured == pytest.approx(expected, abs=1e-9)
    hand = ImitationSetup.from_groups(motion, body="upper_body", controller="thesis", reward="deepmimic",
                                      env="default", data_root=DATA)
    assert hand.env.camera != setup.env.camera  # the hand's groups would differ (its camera, at least)


def test_a_job_s_upper_body_baselines_use_the_upper_body_s_default_controller():
    """Before the one composer, a job's setup (complete groups, no body name) measured its
    thesis-PD baselines with the hand's controller whatever the body; now with the body's own."""
    from aslexp import compose
    from aslexp.envs.assembly import ImitationSetup

    cfg = compose.compose("imitate", ["experiment=signs_mpc", "motion='00433'"])
    setup = ImitationSetup.from_config(cfg, DATA)
    assert setup.controller.name == "upper_body_reference_velocity"
    assert setup.thesis_controller().name == "upper_body"
    hand = ImitationSetup.from_config(compose.compose("imitate", ["controller=reference_velocity"]), DATA)
    assert hand.thesis_controller().name == "thesis"
