"""``hydra/launcher=stacked``: an imitate multirun's jobs trained as one program, each job then a
complete run folder of its own (metrics, curve, run record) whose policy is the one the program
trained; jobs that differ in more than motion and seed are refused in one line; a program stopped
before its end continues from its runs' checkpoints."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from aslexp.compose import compose
from aslexp.errors import ConfigError
from aslexp.jobs.stacked import check_together, train_together
from aslexp.rl.checkpoint import load_checkpoint

from .test_imitation_purposes import NO_FIGURES, ROOT, aslexp

TINY = ["engine=mujoco", "ppo=fast", "ppo.num_envs=2", "ppo.total_steps=512", "ppo.steps_per_rollout=256",
        "ppo.minibatch_size=128", "ppo.epochs=1", "ppo.eval_interval=256", "ppo.eval_steps=40",
        "ppo.eval_episodes=1", "ppo.eval_at_start=true"]


def _rows(run: Path) -> list[dict]:
    with open(run / "progress.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def test_a_multirun_trained_together_gives_each_job_its_own_complete_run(tmp_path, data_root):
    sweep = tmp_path / "sweep"
    proc = aslexp(ROOT, data_root, "imitate", "-m", "motion=A,B", "seed=3", *TINY, *NO_FIGURES,
                  "hydra/launcher=stacked", f"hydra.sweep.dir={sweep}")
    assert "2 runs as one program" in proc.stdout + proc.stderr
    for job, motion in (("0", "A"), ("1", "B")):
        run = sweep / job
        metrics = json.loads((run / "metrics.json").read_text())
        record = json.loads((run / "run.json").read_text())
        assert metrics["motion"] == motion and metrics["seed"] == 3 and record["status"] == "completed"
        assert metrics["steps"] == 512 and metrics["stopped"] == "total_steps" and metrics["num_envs"] == 2
        assert metrics["trained_together"]["runs"] == 2 and "resumed_from" not in metrics
        rows = _rows(run)
        evaluated = [float(r["eval_reward"]) for r in rows if r.get("eval_reward")]
        assert [int(r["step"]) for r in rows] == [0, 256, 512] and len(evaluated) == 3
        # the headline is the program's last evaluation of this run's policy, scored again here
        assert metrics["last_eval"] == pytest.approx(evaluated[-1], abs=1e-5)
        assert metrics["untrained_eval"] == pytest.approx(evaluated[0], abs=1e-5)
        assert set(metrics["baselines"]) == {"reference", "lookahead"}
        assert load_checkpoint(run / "checkpoints" / "last.pt")["stacked"]["runs"] == 2
    # the two runs imitated their own motions: their baselines differ
    a, b = (json.loads((sweep / j / "metrics.json").read_text())["baselines"] for j in "01")
    assert a != b


def test_jobs_that_differ_in_more_than_motion_and_seed_are_refused_naming_the_key(tmp_path, data_root):
    cfgs = [compose("imitate", ["engine=mujoco", f"motion={m}", f"ppo.learning_rate={lr}"])
            for m, lr in (("A", 1e-4), ("B", 3e-4))]
    with pytest.raises(ConfigError, match=r"ppo\.learning_rate is 0\.0001 in one job and 0\.0003 in another"):
        check_together(cfgs)
    with pytest.raises(ConfigError, match=r"policy="):
        check_together([{**cfgs[0], "policy": "outputs/imitate/x"}])
    check_together([compose("imitate", ["engine=mujoco", f"motion={m}", f"seed={s}"]) for m in "AB" for s in (0, 1)])


def test_a_program_stopped_before_its_end_continues_from_its_runs_checkpoints(tmp_path, data_root):
    folders = [tmp_path / "A", tmp_path / "B"]

    def jobs(total: int) -> list[dict]:
        overrides = [o for o in TINY if not o.startswith("ppo.total_steps")] + [f"ppo.total_steps={total}"]
        return [compose("imitate", [*overrides, f"motion={m}", "seed=1", f"data_root={data_root}"]) for m in "AB"]

    train_together(jobs(256), folders)  # as a program killed after its first update would have left them
    first = [load_checkpoint(f / "checkpoints" / "last.pt") for f in folders]
    summary = train_together(jobs(512), folders)
    assert summary["steps_per_run"] == 512
    for folder, before in zip(folders, first):
        after = load_checkpoint(folder / "checkpoints" / "last.pt")
        assert after["steps"] == 512 and after["history"][:len(before["history"])] == before["history"]
        assert [int(r["step"]) for r in _rows(folder)] == [0, 256, 512]  # the untrained row kept, not repeated
        adam_steps = [max(int(s["step"]) for s in c["optimizer"]["state"].values()) for c in (before, after)]
        assert adam_steps[1] > adam_steps[0] > 0  # the Adam state went on from the checkpoint's
    # a folder set that is not one program's is refused, nothing trained
    (folders[1] / "checkpoints" / "last.pt").unlink()
    with pytest.raises(ConfigError, match="no one program at one step"):
        train_together(jobs(768), folders)


def test_the_gpu_sized_variant_differs_from_the_thesis_ppo_where_its_file_says_only():
    from aslexp.rl.ppo import PPOConfig

    thesis = compose("imitate", ["experiment=letters_thesis"])["ppo"]
    gpu = compose("imitate", ["experiment=letters_thesis", "ppo=hand_gpu"])["ppo"]
    assert {k for k in thesis if thesis[k] != gpu[k]} == {
        "name", "num_envs", "steps_per_rollout", "minibatch_size", "epochs", "learning_rate", "eval_interval",
        "rollout_device"}
    config = PPOConfig.parse(gpu)
    assert config.steps_per_env == 16 and config.batch_size // config.minibatch_size == 8
