"""The three thesis overlays end to end on a tiny budget: runs, the thesis table with every
no-learning baseline under the same reward, last evaluations over seeds, pending cells when untrained."""

from __future__ import annotations

import csv
import json

import pytest

from .test_jobs import run_job

# One environment in process: the overlays' 10 worker processes (the thesis' 10 environments) cost a
# minute of start-up per run on 2 cores and change no number here (workers: tests/imitation/test_ppo_vector.py).
TINY = ["ppo.num_envs=1", "ppo.hidden_sizes=[32,32]", "ppo.steps_per_rollout=128", "ppo.minibatch_size=128", "ppo.epochs=1",
        "ppo.total_steps=128", "ppo.eval_interval=128", "ppo.eval_steps=24", "report.baseline_seconds=0.1",
        "render.frames_every=8", "render.size=[48,48]"]


def table(sweep):
    with open(sweep / "thesis_table.csv", newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_letters_thesis_runs_end_to_end(tmp_path):
    sweep = tmp_path / "letters"
    run_job("imitate", "-m", "experiment=letters_thesis", "motion=B", "seed=0,1", *TINY, f"hydra.sweep.dir={sweep}")
    config = json.loads((sweep / "0" / "run.json").read_text())
    assert config["status"] == "completed"
    [row] = table(sweep)
    assert row["motion"] == "B" and row["thesis"].startswith("0.8-0.95")
    assert row["learned, last evaluation"].endswith("(n=2)")
    baselines = [k for k in row if "step ahead" in k or k.endswith("reference")]
    assert "thesis PD (position, kp 0.22, kd 0.87), 240 Hz, 1 step ahead" in baselines
    assert any(k.startswith("aslexp: reference-velocity PD") for k in baselines)
    assert all(0.0 < float(row[k]) <= 1.0 for k in baselines)
    assert row["seeds above every baseline"] == "0/2"  # 128 steps of PPO beat no controller
    stored = json.loads((sweep / "thesis_baselines.json").read_text())["B"]
    assert {b["control_hz"] for b in stored} == {240.0, 30.0}
    assert (sweep / "thesis_curves.png").stat().st_size > 0 and (sweep / "0" / "imitation.gif").is_file()


@pytest.mark.parametrize("overlay, thesis", [("signs_thesis_run1", "0.297 ± 0.166 (Table 6.7 Run 1)"),
                                             ("signs_thesis_run2", "0.745 ± 0.018 (Table 6.7 Run 2)")])
def test_signs_thesis_overlays_run_end_to_end(tmp_path, overlay, thesis):
    sweep = tmp_path / overlay
    extra = ["ppo.total_steps=0"] if overlay.endswith("run2") else []  # untrained: learned cells pending
    run_job("imitate", "-m", f"experiment={overlay}", "motion='69318'", "seed=0", *TINY, *extra,
            "plots=false", "render.gif=false", f"hydra.sweep.dir={sweep}")  # figures: the letters test
    resolved = (sweep / "0" / ".hydra" / "config.yaml").read_text()
    assert "base: free" in resolved and "mode: stable_pd" in resolved and "control_hz: 240" in resolved
    [row] = table(sweep)
    assert row["motion"] == "69318 (father)" and row["thesis"] == thesis
    assert float(row["thesis PD (body stable PD, hands position 0.22/0.87), pinned base, 240 Hz, 1 step ahead"]) > 0.5
    assert "thesis PD (body stable PD, hands position 0.22/0.87), standing (free base), 240 Hz, reference" in row
    assert float(row["authors' code: stable PD, hands 50/0.5, pinned base, 240 Hz, 1 step ahead"]) > 0.5
    assert any(k.startswith("aslexp: reference-velocity PD") for k in row)
    if extra:
        assert row["learned, last evaluation"] == "pending"
    else:
        assert row["learned, last evaluation"].endswith("(n=1)")
