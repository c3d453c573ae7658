"""Every config composes under the Hydra 1.4 pre-release, which refuses a ``version_base`` below
"1.3" (every initialize / hydra.main / compose of the project sets "1.3"). Hydra 1.4 and its
OmegaConf 2.4 are installed from PyPI into a folder of the test's own and put first on the path of
fresh interpreters (a few seconds); without PyPI the test skips and says so."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from test_sweep_files import SWEEPS, _job

from aslexp import cli
from aslexp.paths import CONF_DIR

PROJECT_ROOT = Path(__file__).resolve().parents[2]
PRERELEASE = ("hydra-core>=1.4.0.dev0,<1.5", "omegaconf>=2.4.1rc1,<2.5")
# conf/results.yaml is the results catalogue, read as plain YAML (aslexp.results.catalogue), not a job's
# config: its commands keep the Hydra interpolations (${hydra:job.num}) of the jobs they launch.
JOBS = sorted(p.stem for p in Path(CONF_DIR).glob("*.yaml") if p.stem != "results")

COMPOSE_ALL = r"""
import json, sys, warnings
import hydra
from hydra import compose, initialize_config_dir
from hydra.core.hydra_config import HydraConfig
from aslexp import compose as aslexp_compose
from aslexp.paths import CONF_DIR

warnings.simplefilter("ignore")  # 1.4 deprecates version_base (for 1.5); refusing one is an error
cases = json.loads(sys.argv[1])
with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
    for job, overrides in cases:
        try:
            cfg = compose(job, overrides=overrides, return_hydra_config=True)
        except Exception as error:
            sys.exit(f"{job} {' '.join(overrides)}: {type(error).__name__}: {error}")
for job in sorted({job for job, _ in cases}):
    aslexp_compose.compose(job, [])  # the composer below the jobs (Hydra's config loader)
print(hydra.__version__, len(cases))
"""


@pytest.fixture(scope="module")
def hydra_prerelease(tmp_path_factory) -> Path:
    target = tmp_path_factory.mktemp("hydra14")
    try:
        proc = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--pre", "--no-deps", "--target",
                               str(target), *PRERELEASE], capture_output=True, text=True, timeout=180)  # fmt: skip
    except subprocess.TimeoutExpired:
        pytest.skip("pip could not fetch the Hydra 1.4 pre-release in 180 s")
    if proc.returncode != 0:
        pytest.skip(f"the Hydra 1.4 pre-release could not be installed: {proc.stderr.strip()[-300:]}")
    return target


def _run(args: list[str], target: Path, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(target), os.environ.get("PYTHONPATH", "")]),
           "HYDRA_FULL_ERROR": "0", "MPLBACKEND": "Agg"}  # fmt: skip
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


@pytest.mark.slow  # about a hundred compositions in a fresh interpreter
def test_every_config_composes_under_the_hydra_1_4_prerelease(hydra_prerelease, tmp_path):
    cases = [(job, []) for job in JOBS]
    cases += [(job, [f"experiment={name}"]) for job in JOBS for name in cli.experiments_of(job)]
    cases += [(job, [f"experiment={name}"]) for job in JOBS for name in cli.experiments_of(job, archived=True)]
    cases += [(_job(sweep), [f"+sweeps={sweep}"]) for sweep in SWEEPS]
    cases += [("quadratic", ["+sweeps=quadratic", f"hydra/launcher={launcher}"]) for launcher in ("local", "slurm")]
    cases += [("quadratic", ["+sweeps=quadratic", f"hydra/sweeper/sampler={p.stem}"])
              for p in sorted((Path(CONF_DIR) / "hydra" / "sweeper" / "sampler").glob("*.yaml"))]
    cases += [("quadratic", ["+sweeps=quadratic", f"hydra/sweeper/pruner={p.stem}"])
              for p in sorted((Path(CONF_DIR) / "hydra" / "sweeper" / "pruner").glob("*.yaml"))]
    proc = _run(["-c", COMPOSE_ALL, json.dumps(cases)], hydra_prerelease, tmp_path)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    version, composed = proc.stdout.split()[-2:]
    assert version.startswith("1.4.") and int(composed) == len(cases) > 60


def test_a_job_and_a_sweep_run_under_the_hydra_1_4_prerelease(hydra_prerelease, tmp_path):
    run_dir = tmp_path / "run"
    single = _run(["-m", "aslexp.jobs.quadratic", "x=0.3", f"hydra.run.dir={run_dir}"], hydra_prerelease, tmp_path)
    assert single.returncode == 0, single.stderr[-3000:]
    info = json.loads((run_dir / "run.json").read_text())
    assert info["status"] == "completed" and info["versions"]["hydra-core"].startswith("1.4.")
    sweep = tmp_path / "sweep"
    swept = _run(["-m", "aslexp.jobs.quadratic", "-m", "+sweeps=quadratic", f"hydra.sweep.dir={sweep}",
                  "hydra.sweeper.n_trials=2", "hydra.sweeper.sampler.seed=7"], hydra_prerelease, tmp_path)  # fmt: skip
    assert swept.returncode == 0, swept.stderr[-3000:]
    runs = [json.loads(p.read_text()) for p in sweep.glob("*/run.json")]
    assert [r["status"] for r in runs] == ["completed", "completed"]
