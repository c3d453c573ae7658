"""Every command of docs/sweeps.md, and the sweep and run commands of the README and the how-to pages
(docs/howto_*.md), runs.

The commands are read from the documents' ```bash blocks, so a command that stops working, or a
new one, is caught here. They run as written, on tiny budgets: counts, sizes and cluster
resources are replaced by small ones (see ``_tiny``), `/shared/...` by a temporary folder, the
database URL by the test database, and recognition gets ``experiment=debug`` (2 epochs, short
clips). The Slurm recipes run on the loopback cluster of scripts/ci_slurm.sh.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import socket
import subprocess
import sys
import time
import urllib.request
import uuid
from dataclasses import dataclass
from pathlib import Path

import pytest
import job_process
from slurm_helpers import PROJECT_ROOT, accounting, require_cluster, wait_for_jobs

DOC = PROJECT_ROOT / "docs" / "sweeps.md"
README = PROJECT_ROOT / "README.md"
HOWTOS = sorted((PROJECT_ROOT / "docs").glob("howto_*.md"))  # their other commands: tests/extraction
SHARED = PROJECT_ROOT.parent / "shared" / "data"

# Documented value -> test value, by override key (or sbatch option). The trial budget: one trial,
# or one per worker where there are several.
_SMALL = {"hydra.launcher.partition": "debug", "hydra.launcher.timeout_min": "10",
          "hydra.launcher.cpus_per_task": "1", "hydra.launcher.gpus_per_node": "0",
          "hydra.launcher.mem_gb": "2"}
_SBATCH = {"--array": "1-2", "--partition": "debug", "--cpus-per-task": "1", "--time": "10"}
_EXTRA = {"recognize": ["experiment=debug", "trainer.max_epochs=1"],
          "tune_pd": ["tuning.random.seconds=1.0"]}


@dataclass
class Command:
    text: str            # as documented (continuations joined)
    script: bool = False  # an sbatch file rather than a command line

    @property
    def needs_slurm(self) -> bool:
        return self.script or "hydra/launcher=slurm" in self.text

    @property
    def needs_postgres(self) -> bool:
        return "postgresql://" in self.text


def documented(path: Path, keep=lambda line: True) -> list[Command]:
    """The commands of every ```bash block of ``path`` (comments dropped, lines joined)."""
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", path.read_text(encoding="utf-8"), re.S):
        text = block.replace("\\\n", " ")
        lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
        if lines and re.match(r"# \S+\.sbatch", lines[0]):
            commands.append(Command("\n".join(lines), script=True))
            continue
        for line in lines:
            line = re.split(r"\s+#\s", line, maxsplit=1)[0].strip()
            if line.startswith("aslexp ") and keep(line):
                commands.append(Command(re.sub(r"\s+", " ", line)))
    return commands


def _tiny(args: list[str], tmp: Path, pg_url: str | None) -> list[str]:
    """The documented overrides, with small budgets and this machine's resources."""
    out, keys = [], set()
    # Several workers on this machine: two, a trial each. On Slurm one (recipe A's trials in
    # flight together are tested in test_slurm.py): every Slurm trial costs a job start.
    workers = "1" if "hydra/launcher=slurm" in args else "2"
    trials = workers if any(a.startswith("hydra.sweeper.n_workers=") for a in args) else "1"
    for arg in args:
        key, eq, value = arg.partition("=")
        keys.add(key.lstrip("+~"))
        if key == "hydra.sweeper.n_trials":
            arg = f"{key}={trials}"
        elif key == "hydra.sweeper.n_workers":
            arg = f"{key}={workers}"
        elif eq and key in _SMALL:
            arg = f"{key}={_SMALL[key]}"
        elif key == "hydra.sweeper.storage" and "postgresql://" in value:
            arg = f"{key}='{pg_url}'"
        elif key == "hydra.sweeper.study_name":
            arg = f"{key}={value}_{uuid.uuid4().hex[:8]}"  # a fresh study in the shared database
        out.append(arg.replace("/shared/", f"{tmp}/shared/"))
    job = args[0] if args else ""
    if "-m" in args and "hydra.sweeper.n_trials" not in keys:
        out.append(f"hydra.sweeper.n_trials={trials}")
    return out + [e for e in _EXTRA.get(job, []) if e.split("=")[0] not in keys]


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> tuple[Path, dict]:
    tmp = tmp_path_factory.mktemp("docs")
    env = {**os.environ, "ASLEXP_DATA_ROOT": str(SHARED), "MPLBACKEND": "Agg",
           "ASLEXP_CACHE_DIR": str(tmp_path_factory.mktemp("cache"))}
    return tmp, env


def _aslexp(args: list[str], cwd: Path, env: dict, timeout: float = 600) -> subprocess.CompletedProcess:
    proc = job_process.run([sys.executable, "-m", "aslexp.cli", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, (f"`aslexp {shlex.join(args)}` exited {proc.returncode}:\n"
                                  f"{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}")
    return proc


def _serve_once(args: list[str], cwd: Path, env: dict) -> None:
    """`sweep dashboard`: it serves the study; then it is stopped."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "aslexp.cli", *args, "--port", str(port)],
                            cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/studies", timeout=2) as r:
                    assert json.loads(r.read())["study_summaries"]
                return
            except OSError:
                assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()[1][-2000:]
                time.sleep(0.3)
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def _run(command: Command, tmp: Path, env: dict, pg_url: str | None) -> subprocess.CompletedProcess | None:
    args = _tiny(shlex.split(command.text)[1:], tmp, pg_url)
    if args[:2] == ["sweep", "dashboard"]:
        return _serve_once(args, tmp, env)
    return _aslexp(args, tmp, env)


def _run_sbatch(command: Command, tmp: Path, env: dict, pg_url: str | None) -> None:
    """Recipe B as documented: the sbatch file, with small resources, submitted and awaited."""
    lines = command.text.splitlines()
    head = [ln for ln in lines if ln.startswith("#SBATCH")]
    body = [ln for ln in lines if ln.startswith("aslexp ")]
    options = []
    for option in shlex.split(" ".join(h[len("#SBATCH"):] for h in head)):
        key, _, value = option.partition("=")
        if key == "--gres":
            continue  # no GPUs here
        options.append(f"{key}={_SBATCH.get(key, value)}")
    options += ["--mem=2G", f"--output={tmp}/sweep_worker-%a.out"]
    script = tmp / "sweep_worker.sbatch"
    commands = [shlex.join([sys.executable, "-m", "aslexp.cli", *_tiny(shlex.split(b)[1:], tmp, pg_url)])
                for b in body]
    script.write_text("#!/bin/bash\n" + f"#SBATCH {' '.join(options)}\n" + f"cd {shlex.quote(str(tmp))}\n"
                      + "\n".join(commands) + "\n")
    job = subprocess.run(["sbatch", "--parsable", str(script)], env=env, capture_output=True,
                         text=True, check=True).stdout.strip()
    wait_for_jobs([job], timeout=600)
    rows = accounting([job], array_tasks=(1, 2))
    logs = "\n".join(p.read_text() for p in sorted(tmp.glob("sweep_worker-*.out")))
    assert len(rows) == 2 and {r["State"] for r in rows.values()} == {"COMPLETED"}, f"{rows}\n{logs[-3000:]}"


def test_the_sweeps_doc_runs_on_one_machine(workspace):
    tmp, env = workspace
    commands = [c for c in documented(DOC) if not c.needs_slurm and not c.needs_postgres]
    texts = [c.text for c in commands]
    assert any("+sweeps=classifier_mlp" in t for t in texts) and any("sweep dashboard" in t for t in texts)
    for command in commands:
        _run(command, tmp, env, None)
    # What they made: the overlay sweep, the command-line sweep, the parallel tune_pd sweep.
    for folder, trials in (("mlp", 1), ("mlp_cli", 1), ("pd", 2)):
        runs = [json.loads(p.read_text()) for p in (tmp / "outputs" / "sweeps" / folder).rglob("run.json")]
        assert len(runs) == trials and {r["status"] for r in runs} == {"completed"}, folder
    cli_space = json.loads((tmp / "outputs" / "sweeps" / "mlp_cli" / "sweep.json").read_text())["params"]
    assert set(cli_space) == {"trainer.lr", "trainer.batch_size", "classifier.params.dropout"}
    assert (tmp / "outputs" / "sweeps" / "mlp" / "report" / "trials.csv").is_file()


def test_the_sweeps_doc_slurm_recipes_run_on_a_real_cluster(workspace):
    from sweep_helpers import postgres_url

    require_cluster()
    pg_url = postgres_url()
    if pg_url is None:
        pytest.skip("recipe B needs the test PostgreSQL server: bash scripts/ci_postgres.sh")
    tmp, env = workspace
    commands = [c for c in documented(DOC) if c.needs_slurm]
    assert len(commands) == 2  # recipe A, recipe B
    for command in commands:
        (_run_sbatch if command.script else _run)(command, tmp, env, pg_url)
    runs = [json.loads(p.read_text()) for p in (tmp / "shared" / "sweeps" / "mlp").rglob("run.json")]
    # Recipe A: one trial; recipe B (its own study: studies/<name>/): 2 tasks, 1 trial.
    assert len(runs) == 1 + 1 and all(r["status"] == "completed" and r["slurm"] for r in runs)


def test_the_readme_and_howto_sweep_and_run_commands_run(workspace):
    tmp, env = workspace
    keep = lambda line: "+sweeps=" in line or line.startswith(("aslexp sweep ", "aslexp runs "))  # noqa: E731
    commands = [c for path in (README, *HOWTOS) for c in documented(path, keep)]
    assert len(commands) == 5, [c.text for c in commands]
    for command in commands:
        text = command.text
        if "RUN_A RUN_B" in text:  # placeholders: two run folders made by the commands above
            found = (sorted((tmp / "outputs").rglob("run.json")) * 2)[:2]  # alone: one run, twice
            text = text.replace("RUN_A RUN_B", " ".join(str(p.parent) for p in found))
        _run(Command(text), tmp, env, None)
