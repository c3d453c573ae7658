"""The engine seam: an engine is one module plus one YAML, registered from outside
aslexp; the environment, PD control, batching and the imitate job talk to the seam alone.

The engine registered here is ``replay_engine.py`` beside this file (test only): it moves the body to
its PD targets, a perfect tracker, so the reference-as-target baseline has no pose error at all.
"""

from __future__ import annotations

import ast
import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest
import job_process

from aslexp.errors import ConfigError
from aslexp.sim import engine as engines

from .registration import fresh_registration

HERE = Path(__file__).resolve().parent
SRC = HERE.parents[1] / "src" / "aslexp"
REPLAY = {"name": "replay", "module": "replay_engine"}


@pytest.fixture
def replay(monkeypatch):
    """The replay engine found through its YAML's ``module`` key, as a user's would be."""
    for _ in fresh_registration(monkeypatch, "replay_engine", lambda: engines.unregister_engine("replay")):
        yield REPLAY


def _rollout(env, steps: int = 30) -> list[dict]:
    env.reset(options={"time": 0.0})
    return [env.step(env.reference_action(1))[4] for _ in range(steps)]


def test_a_registered_engine_runs_the_environment_with_no_edit_elsewhere(replay, data_root):
    from aslexp.envs.imitation import ImitationEnv

    assert "replay" not in engines._ENGINES
    env = ImitationEnv(data_root / "motions/hand/A.txt", engine=replay, data_root=data_root)
    assert "replay" in engines.engine_names() and env.engine_spec.options.lag == 0.0
    infos = _rollout(env)
    # the body is where the targets (the reference one step ahead) put it: no pose, no tip error
    assert max(i["e_pose"] for i in infos) < 1e-12 and max(i["e_end_effector"] for i in infos) < 1e-12
    assert env.sim.drives == 30 and not any(i["diverged"] for i in infos)
    env.close()
    lagging = ImitationEnv(data_root / "motions/hand/A.txt", engine={**replay, "lag": 0.5}, data_root=data_root)
    assert np.mean([i["e_pose"] for i in _rollout(lagging)]) > 1e-3  # its own key reaches it
    lagging.close()


def test_the_seam_refuses_what_an_engine_does_not_declare(replay, data_root):
    from aslexp.envs.batched import BatchedImitationEnv
    from aslexp.envs.imitation import ImitationEnv

    with pytest.raises(ConfigError, match=r"engine.integrator=Euler: unknown key; expected one of lag"):
        ImitationEnv(data_root / "motions/hand/A.txt", engine={**replay, "integrator": "Euler"}, data_root=data_root)
    with pytest.raises(ConfigError, match="name must be one of .*'mujoco'.*got 'warp'"):
        engines.EngineSpec.parse({"name": "warp"})
    with pytest.raises(ConfigError, match="module no_such_module could not be imported"):
        engines.EngineSpec.parse({"name": "warp", "module": "no_such_module"})
    # a batch needs an engine that batches: the error names those that do (engine=mjx joins the list
    # once another test in this worker has imported it)
    with pytest.raises(ValueError, match=r"the engine is 'replay' \(one that batches: \[('mjx', )?'mujoco'\]"):
        BatchedImitationEnv(2, data_root / "motions/hand/A.txt", engine=replay, data_root=data_root)
    # a second, different engine under a taken name is refused
    with pytest.raises(ConfigError, match="already registered"):
        engines.register_engine("replay")(lambda spec, request: None)
    assert engines.batching_engines() in (["mujoco"], ["mjx", "mujoco"])


def test_the_imitate_job_runs_an_engine_from_a_yaml_and_a_module(tmp_path):
    conf = tmp_path / "conf" / "engine"
    conf.mkdir(parents=True)
    (conf / "replay.yaml").write_text("name: replay\nmodule: replay_engine\nlag: 0.0\n")
    run = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")])}
    done = job_process.run([sys.executable, "-m", "aslexp.cli", "imitate", "--config-dir", str(tmp_path / "conf"),
                           "engine=replay", "ppo.total_steps=0", "render.gif=false", "render.mp4=false", "plots=false",
                           f"hydra.run.dir={run}"], capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    metrics = json.loads((run / "metrics.json").read_text())
    # the one-step-ahead reference baseline, replayed exactly: only the velocity term is short of 1
    assert metrics["baselines"]["lookahead"] > 0.94 and metrics["untrained_eval_diverged"] == 0
    assert "engine" in (run / ".hydra" / "config.yaml").read_text()


def _engine_words(path: Path) -> list[str]:
    """String literals (docstrings aside) naming a built-in engine, and imports of one, in ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                  if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                  and node.body and isinstance(node.body[0], ast.Expr) and isinstance(node.body[0].value, ast.Constant)}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
            if any(word in node.value.lower() for word in engines.BUILT_IN):
                found.append(f"{path.name}:{node.lineno} {node.value[:60]!r}")
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names = [a.name for a in node.names] + [getattr(node, "module", None) or ""]
            if any(n.split(".")[0] in {"pybullet", "pybullet_data", "pybullet_utils", "mujoco"} or
                   n.endswith(("sim.world", "sim.mujoco_engine")) for n in names):
                found.append(f"{path.name}:{node.lineno} import")
    return found


@pytest.mark.parametrize("room", ["envs", "rl", "jobs", "tuning", "runs", "reports", "measure", "control"])
def test_no_room_above_the_engines_names_or_imports_one(room):
    # what differs between engines is data (conf/engine/*.yaml `report:`, conf/engine_agreement.yaml);
    # tests/platform/test_engine_names.py reads comments and docstrings too
    found = [hit for path in sorted((SRC / room).rglob("*.py")) for hit in _engine_words(path)
             if not hit.startswith("record.py")]  # runs/record.py lists installed package versions
    assert found == []
