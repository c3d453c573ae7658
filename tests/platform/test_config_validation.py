"""Bad config values are refused at the edge: one line naming the key, the value given
and what is expected, exit 2, and no run folder; the shipped configs all pass. The real CLI in a
subprocess; the schema (aslexp.config_schema) and the readers that share it in-process."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
from platform_helpers import error_lines

from aslexp.config_schema import JOBS, PPO, TRAINER, check_section
from aslexp.errors import ConfigError

CONF = Path(__file__).resolve().parents[2] / "conf"


@pytest.mark.parametrize("job, override, expected", [
    ("imitate", "ppo.total_steps=abc", "ppo.total_steps=abc: expected an integer >= 0"),
    ("imitate", "ppo.total_steps=-4096", "ppo.total_steps=-4096: expected an integer >= 0"),
    ("imitate", "ppo.total_steps=4096.5", "ppo.total_steps=4096.5: expected an integer >= 0"),
    ("imitate", "ppo.eval_interval=0", "ppo.eval_interval=0: expected a positive integer"),
    ("imitate", "ppo.gamma=1.5", "ppo.gamma=1.5: expected a number in [0, 1]"),
    ("imitate", "ppo.vector_env=threads",
     "ppo.vector_env=threads: expected one of auto, sync, async, workers, batched"),
    ("recognize", "trainer.max_epochs=abc", "trainer.max_epochs=abc: expected a positive integer"),
    ("recognize", "n_seeds=0", "n_seeds=0: expected a positive integer"),
    ("tune_pd", "seed=1.5", "seed=1.5: expected an integer >= 0"),
    # gains and rates are range-checked too
    ("imitate", "controller.groups.default.kd=-1e6",
     "controller.groups.default.kd=-1000000.0: expected a finite number >= 0"),
    ("imitate", "controller.groups.default.kp=inf", "controller.groups.default.kp=inf: expected a finite number >= 0"),
    ("imitate", "controller.groups.default.max_force=0",
     "controller.groups.default.max_force=0: expected a positive finite number"),
    ("imitate", "env.control_hz=0.001", "env.control_hz=0.001: expected a number in [1, 10000]"),
    ("imitate", "env.physics_hz=1e9", "env.physics_hz=1000000000.0: expected a number in [1, 100000]"),
    ("imitate", "env.control_hz=7", "env.physics_hz=240: expected a whole multiple of control_hz (7): 1x, 2x, ..."),
    ("tune_pd", "controller.groups.default.kd=-1", "controller.groups.default.kd=-1: expected a finite number >= 0"),
    ("tune_pd", "env.control_hz=0.5", "env.control_hz=0.5: expected a number in [1, 10000]"),
    ("tune_pd", "tuning.kp=inf", "tuning.kp=inf: expected null or a finite number >= 0"),
])
def test_a_bad_value_is_one_line_exit_2_and_no_run_folder(aslexp, tmp_path, job, override, expected):
    run_dir = tmp_path / "run"
    proc = aslexp(job, override, f"hydra.run.dir={run_dir}", check=False, timeout=120)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert error_lines(proc.stderr) == [f"aslexp {job}: {expected}"]
    assert not run_dir.exists()  # refused before Hydra wrote anything: no folder, no run


def test_a_choice_that_needs_more_names_the_whole_fix_at_once(aslexp, tmp_path):
    """The 240 Hz tracking PD on the thesis' hand took three tries, each error naming
    one more override; the first refusal names them all, and the overrides it names then compose."""
    from hydra import compose, initialize_config_dir

    from aslexp.jobs.validation import check_config

    run_dir = tmp_path / "run"
    chosen = ["experiment=letters_thesis", "controller=reference_velocity_tuned", "env.action_range=motion"]
    proc = aslexp("imitate", *chosen, f"hydra.run.dir={run_dir}", check=False, timeout=120)
    assert proc.returncode == 2, proc.stderr[-2000:]
    [line] = error_lines(proc.stderr)
    assert line.startswith("aslexp imitate: controller reference_velocity_tuned: target_rate=physics needs "
                           "env.action_mode=residual")
    assert line.endswith("Add: env.action_mode=residual env.action_range=joint")
    assert not run_dir.exists()
    with initialize_config_dir(config_dir=str(CONF.resolve()), version_base="1.3"):
        fixed = compose("imitate", overrides=chosen + line.split("Add: ")[1].split())
    check_config("imitate", fixed)  # nothing more needed


def test_an_experiment_that_cannot_be_assembled_is_refused_before_its_run_folder(aslexp, tmp_path):
    """A refusal found when the experiment is assembled (here a whole sign on the
    hand) used to leave a failed run folder; it is found at the edge now, exit 2, no folder."""
    run_dir = tmp_path / "run"
    proc = aslexp("imitate", "motion='00433'", f"hydra.run.dir={run_dir}", check=False, timeout=120)
    assert proc.returncode == 2, proc.stderr[-2000:]
    [line] = error_lines(proc.stderr)
    assert line.startswith("aslexp imitate: MotionFormatError: ") and "body=upper_body" in line
    assert "run folder" not in line and not run_dir.exists()


def test_a_multirun_refuses_a_shared_bad_value_and_fails_only_the_job_with_a_swept_one(aslexp, tmp_path):
    shared = tmp_path / "shared"
    proc = aslexp("imitate", "-m", "ppo.total_steps=abc", "seed=0,1", f"hydra.sweep.dir={shared}", check=False,
                  timeout=120)
    assert proc.returncode == 2
    assert error_lines(proc.stderr) == ["aslexp imitate: ppo.total_steps=abc: expected an integer >= 0"]
    assert not shared.exists()

    swept = tmp_path / "swept"  # job 0 is refused in its body and recorded failed; job 1 runs
    aslexp("tune_pd", "-m", "seed=-1,0", "tuning.random.seconds=0.5", f"hydra.sweep.dir={swept}", timeout=300)
    runs = {p.parent.name: json.loads(p.read_text()) for p in swept.glob("*/run.json")}
    assert runs["0"]["status"] == "failed" and runs["0"]["error"] == "seed=-1: expected an integer >= 0"
    assert runs["1"]["status"] == "completed"


def test_every_shipped_config_passes():
    from hydra import compose, initialize_config_dir

    from aslexp import cli
    from aslexp.jobs.validation import check_config

    def stems(group: str) -> list[str]:
        return sorted(p.stem for p in (CONF / group).glob("*.yaml"))

    def listed(job: str) -> list[list[str]]:
        """The overlays `aslexp JOB --help` lists for the job, catalogue and archive: each composes for
        it here (tests/platform/test_job_help_overlays.py checks the help itself)."""
        return [[f"experiment={e}"] for e in cli.experiments_of(job) + cli.experiments_of(job, archived=True)]

    # Every experiment with the job that lists it, every trainer; each ppo file alone is read through
    # the same schema by tests/imitation/test_ppo_vector.py (PPOConfig.parse of every conf/ppo file).
    experiments = stems("experiment") + [f"archive/{e}" for e in stems("experiment/archive")]
    choices = {
        "imitate": [[]] + listed("imitate"),
        "recognize": [[f"trainer={t}"] for t in stems("trainer")] + listed("recognize")
                     + [["classifier=slgcn"], ["classifier=gru_thesis_ch3", "trainer=thesis_ch3"]],
        "tune_pd": [[]] + listed("tune_pd"),
    }
    checked = 0
    with initialize_config_dir(str(CONF), version_base="1.3"):
        for job, override_sets in choices.items():
            for overrides in override_sets:
                check_config(job, compose(job, overrides=overrides))
                checked += 1
    composed = [o for sets in choices.values() for overrides in sets for o in overrides if o.startswith("experiment=")]
    assert sorted(o.split("=", 1)[1] for o in composed) == sorted(experiments) and len(experiments) >= 28
    assert checked == 1 + len(experiments) + len(stems("trainer")) + 2 + 1


def test_the_schema_declares_every_key_its_readers_accept():
    from aslexp.recognition.train import TrainerConfig
    from aslexp.rl.ppo import PPOConfig

    assert set(PPO) == {f.name for f in dataclasses.fields(PPOConfig)}
    assert set(TRAINER) == {f.name for f in dataclasses.fields(TrainerConfig)}
    assert set(JOBS) == {"imitate", "recognize", "signing", "tune_pd"}
    # Choices declared in the schema are the readers' own lists.
    from aslexp.data.preprocess import PADDINGS
    from aslexp.data.splits import RARE_RULES
    from aslexp.envs.tracking import OBJECTIVES
    from aslexp.recognition.device import PRECISIONS
    from aslexp.rl.policy import ACTIVATIONS
    from aslexp.rl.vector import MODES

    recognize, tune_pd = JOBS["recognize"], JOBS["tune_pd"]
    assert recognize["data.padding"].choices == PADDINGS and recognize["split.rare_classes"].choices == RARE_RULES
    assert tuple(tune_pd["tuning.objective"].choices) == tuple(OBJECTIVES)
    assert TRAINER["precision"].choices == PRECISIONS
    assert PPO["activation"].choices == tuple(ACTIVATIONS) and PPO["vector_env"].choices == MODES


def test_integers_are_never_rounded_and_the_readers_refuse_the_same():
    from aslexp.recognition.train import TrainerConfig
    from aslexp.rl.ppo import PPOConfig

    ok = check_section("ppo", {"total_steps": "4096", "eval_interval": 2e6, "num_envs": 4.0, "gamma": 1,
                               "eval_phases": [0, 0.5], "target_kl": None}, PPO)
    assert ok == {"total_steps": 4096, "eval_interval": 2_000_000, "num_envs": 4, "gamma": 1.0,
                  "eval_phases": [0.0, 0.5], "target_kl": None}
    assert type(ok["num_envs"]) is int
    for key, value, message in [
        ("total_steps", 4096.5, "ppo.total_steps=4096.5: expected an integer >= 0"),
        ("total_steps", True, "ppo.total_steps=true: expected an integer >= 0"),
        ("learning_rate", float("nan"), "ppo.learning_rate=nan: expected a number >= 0"),
        ("clip_epsilon", 0, "ppo.clip_epsilon=0: expected a positive number"),
        ("target_kl", "x", "ppo.target_kl=x: expected null or a positive number"),
        ("hidden_sizes", [64, 0], "ppo.hidden_sizes=[64, 0]: expected a list of positive integers"),
        ("eval_phases", [], "ppo.eval_phases=[]: expected null or a non-empty list of numbers in [0, 1)"),
    ]:
        with pytest.raises(ConfigError) as err:
            PPOConfig.parse({key: value})
        assert str(err.value) == message
    with pytest.raises(ConfigError, match=r"^trainer\.max_epochs=abc: expected a positive integer$"):
        TrainerConfig.parse({"max_epochs": "abc"})
    with pytest.raises(ConfigError, match=r"^trainer\.nesterov=yes: expected true or false$"):
        TrainerConfig.parse({"nesterov": "yes"})
    assert TrainerConfig.parse({"precision": "bf16-mixed", "batch_size": 8.0}).batch_size == 8
    with pytest.raises(ConfigError, match=r"^ppo\.epoch=3: unknown key; did you mean ppo\.epochs\?$"):
        check_section("ppo", {"epoch": 3}, PPO)
