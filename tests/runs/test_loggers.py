"""The loggers log: every per-step metric and the configuration, read back from the files they
write (TensorBoard's own EventAccumulator; W&B's offline run), for recognize, imitate and tune_pd."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import job_process
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from tensorboard.plugins.hparams import plugin_data_pb2

from aslexp.runs.loggers import CsvLogger, flatten, wandb_key_available, wandb_mode

ROOT = Path(__file__).resolve().parents[2]
IMITATE_SMALL = ["motion=B", "env=residual", "ppo=fast", "ppo.hidden_sizes=[32,32]", "ppo.steps_per_rollout=128",
                 "ppo.minibatch_size=64", "ppo.epochs=1", "ppo.eval_interval=256", "ppo.eval_steps=20",
                 "ppo.total_steps=512", "render.gif=false", "plots=false"]  # fmt: skip


def run_job(job: str, *overrides: str, env: dict | None = None) -> subprocess.CompletedProcess:
    environ = {**os.environ, "MPLBACKEND": "Agg", **(env or {})}
    environ = {k: v for k, v in environ.items() if v is not None}  # None: unset
    proc = job_process.run([sys.executable, "-m", f"aslexp.jobs.{job}", *overrides], cwd=ROOT, env=environ,
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


def read_tensorboard(run_dir: Path) -> tuple[dict[str, list[tuple[int, float]]], dict[str, object]]:
    """Scalars {tag: [(step, value)]} and the hparams of a run's tensorboard/ folder."""
    events = EventAccumulator(str(run_dir / "tensorboard"), size_guidance={"scalars": 0})
    events.Reload()
    scalars = {tag: [(e.step, e.value) for e in events.Scalars(tag)] for tag in events.Tags()["scalars"]}
    content = events.PluginTagToContent("hparams")["_hparams_/session_start_info"]
    info = plugin_data_pb2.HParamsPluginData.FromString(content).session_start_info
    hparams = {k: getattr(v, v.WhichOneof("kind")) for k, v in info.hparams.items()}
    return scalars, hparams


def test_recognize_logs_every_epoch_and_the_config_to_tensorboard(tmp_path):
    run_dir = tmp_path / "run"
    run_job("recognize", "experiment=debug", "classifier=mlp", "trainer.max_epochs=3", "trainer.patience=3",
            "data.num_frames=32",
            "logger=tensorboard", f"hydra.run.dir={run_dir}", env={"ASLEXP_CACHE_DIR": str(tmp_path / "cache")})
    scalars, hparams = read_tensorboard(run_dir)
    metrics = json.loads((run_dir / "metrics.json").read_text())
    # Every number of every epoch, grouped as SB3 and Lightning users expect.
    for key in ("val/mcc", "val/accuracy", "train/loss", "train/accuracy", "train/lr", "time/epoch_s"):
        assert [step for step, _ in scalars[key]] == [1, 2, 3], key
    assert hparams["classifier/name"] == "mlp" and hparams["trainer/max_epochs"] == 3.0
    assert hparams["property/name"] == "sign_type" and hparams["seed"] == 0.0
    # The run's final numbers are the hparams' metrics.
    assert scalars["hparam/val_mcc"][0][1] == pytest.approx(metrics["val_mcc"], abs=1e-6)
    assert scalars["hparam/test_mcc"][0][1] == pytest.approx(metrics["test"]["mcc"], abs=1e-6)


def test_imitate_logs_every_rollout_and_evaluation(tmp_path):
    run_dir = tmp_path / "imitate"
    run_job("imitate", *IMITATE_SMALL, "logger=tensorboard", f"hydra.run.dir={run_dir}")
    scalars, hparams = read_tensorboard(run_dir)
    with open(run_dir / "progress.csv", newline="") as fh:
        progress = list(csv.DictReader(fh))
    assert len(progress) == 4  # 512 steps in rollouts of 128
    steps = [int(row["step"]) for row in progress]
    # progress.csv keeps its columns; the loggers group them as SB3 users expect.
    for tag in ("time/steps_per_s", "rollout/reward", "train/log_std", "train/learning_rate", "time/seconds"):
        assert [s for s, _ in scalars[tag]] == steps, tag
    evaluated = [int(row["step"]) for row in progress if row.get("eval_reward")]
    assert [s for s, _ in scalars["eval/reward"]] == evaluated == [256, 512]
    assert scalars["eval/reward"][-1][1] == pytest.approx(float(progress[-1]["eval_reward"]), abs=1e-5)
    assert hparams["ppo/steps_per_rollout"] == 128.0 and hparams["motion/name"] == "B"
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert scalars["hparam/best_eval"][0][1] == pytest.approx(metrics["best_eval"], abs=1e-6)


def test_tune_pd_logs_its_evaluation_to_csv(tmp_path):
    run_dir = tmp_path / "tune"
    run_job("tune_pd", "tuning.random.seconds=1.0", "tuning.kp=0.5", "logger=csv", f"hydra.run.dir={run_dir}")
    with open(run_dir / "history.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert len(rows) == 1 and float(rows[0]["objective"]) == pytest.approx(metrics["objective"])
    assert {"pose_error", "velocity_error", "reward"} <= set(rows[0])


def test_csv_logger_extends_its_header(tmp_path):
    logger = CsvLogger(tmp_path)
    logger.log({"loss": 1.0}, 1)
    logger.log({"loss": 0.5, "val_mcc": 0.2}, 2)
    logger.close({"val_mcc": 0.2})
    with open(tmp_path / "history.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert rows == [{"step": "1", "loss": "1.0", "val_mcc": ""}, {"step": "2", "loss": "0.5", "val_mcc": "0.2"}]
    assert flatten({"a": {"b": [1, 2], "c": None}, "d": 3}) == {"a/b": "[1, 2]", "a/c": "None", "d": 3}


def test_wandb_mode_offline_unless_a_key_for_the_wandb_host(tmp_path):
    (tmp_path / ".netrc").write_text("machine github.com login me password secret\n")
    assert not wandb_key_available({}, tmp_path) and wandb_mode(None, {}, tmp_path) == "offline"
    (tmp_path / ".netrc").write_text("machine api.wandb.ai login user password 0123456789abcdef\n")
    assert wandb_mode(None, {}, tmp_path) == "online"
    assert wandb_mode(None, {"WANDB_BASE_URL": "https://wandb.example.org"}, tmp_path) == "offline"
    assert wandb_mode(None, {"WANDB_API_KEY": "k"}, tmp_path / "nowhere") == "online"
    assert wandb_mode(None, {"WANDB_MODE": "disabled"}, tmp_path) is None  # wandb reads it
    assert wandb_mode("offline", {"WANDB_API_KEY": "k"}, tmp_path) == "offline"


def test_wandb_with_a_foreign_netrc_logs_offline(tmp_path):
    pytest.importorskip("wandb", reason="logger=wandb is an optional extra (scripts/setup.sh installs it)")
    home = tmp_path / "home"
    home.mkdir()
    (home / ".netrc").write_text("machine github.com login me password secret\n")
    run_dir = tmp_path / "tune"
    env = {"HOME": str(home), "WANDB_API_KEY": None, "WANDB_MODE": None, "WANDB_SILENT": "true"}
    run_job("tune_pd", "tuning.random.seconds=1.0", "logger=wandb", f"hydra.run.dir={run_dir}", env=env)
    runs = list((run_dir / "wandb").glob("offline-run-*/run-*.wandb"))
    assert len(runs) == 1, list((run_dir / "wandb").iterdir())
    records = wandb_records(runs[0])
    metrics = json.loads((run_dir / "metrics.json").read_text())
    history = [{_key(item): json.loads(item.value_json) for item in r.history.item} for r in records
               if r.WhichOneof("record_type") == "history"]  # fmt: skip
    assert history[0]["objective"] == pytest.approx(metrics["objective"]) and history[0]["step"] == 0
    summary = {}
    for r in records:
        if r.WhichOneof("record_type") == "summary":
            summary.update({_key(item): json.loads(item.value_json) for item in r.summary.update})
    assert summary["objective"] == pytest.approx(metrics["objective"])
    assert summary["pose_error"] == pytest.approx(metrics["pose_error"])
    config = {_key(item): item.value_json for r in records if r.WhichOneof("record_type") == "run"
              for item in r.run.config.update}  # fmt: skip
    assert '"kp"' in config["tuning"] and "groups" in config["controller"]


def test_wandb_that_cannot_go_online_logs_offline(tmp_path):
    """A key, but the server unreachable (or the key refused): a warning, then an offline run."""
    pytest.importorskip("wandb", reason="logger=wandb is an optional extra (scripts/setup.sh installs it)")
    env = {"HOME": str(tmp_path), "WANDB_API_KEY": "0" * 40, "WANDB_BASE_URL": "http://127.0.0.1:9",
           "WANDB_INIT_TIMEOUT": "3", "WANDB_SILENT": "true", "WANDB_MODE": None}
    run_dir = tmp_path / "tune"
    proc = run_job("tune_pd", "tuning.random.seconds=0.5", "logger=wandb", f"hydra.run.dir={run_dir}", env=env)
    printed = proc.stdout + proc.stderr  # Hydra logs to stdout
    assert "wandb could not go online" in printed and "logging offline" in printed
    assert len(list((run_dir / "wandb").glob("offline-run-*/run-*.wandb"))) == 1
    assert json.loads((run_dir / "run.json").read_text())["status"] == "completed"


def _key(item) -> str:
    return item.key or "/".join(item.nested_key)


def wandb_records(path: Path) -> list:
    """The records of a W&B transaction log (``run-*.wandb``; LevelDB's log format: a 7-byte
    header, then 32 KiB blocks of chunks, each checksum (4) length (2) type (1) data)."""
    from wandb.proto import wandb_internal_pb2

    data, pos, block, parts, records = path.read_bytes(), 7, 32768, [], []
    while pos + 7 <= len(data):
        if block - pos % block < 7:  # block trailer padding
            pos += block - pos % block
            continue
        length, kind = int.from_bytes(data[pos + 4 : pos + 6], "little"), data[pos + 6]
        parts.append(data[pos + 7 : pos + 7 + length])
        pos += 7 + length
        if kind in (1, 4):  # FULL, or the LAST of FIRST/MIDDLE/LAST
            record = wandb_internal_pb2.Record()
            record.ParseFromString(b"".join(parts))
            records.append(record)
            parts = []
    return records
