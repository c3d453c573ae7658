"""Run ``python -m MODULE ARGS`` (or ``python SCRIPT.py ARGS``) for a test in a fork of an interpreter that has already imported the
heavy libraries (torch, scikit-learn, SciPy, Matplotlib, Hydra, Optuna, MuJoCo, Gymnasium).

Two thirds of the suite's time is spent in job processes the tests start, and about half of a tiny
job's time is importing those libraries (the suite's budget: 15 minutes on 2 cores). A fork of
a process that imported them and did nothing else starts a job in milliseconds. The job is the same
code in a real process of its own: its own pid, folder, environment, stdin, stdout, stderr, exit code
and the interpreter's normal exit (atexit handlers, log flushing); aslexp itself is imported afresh
in every job, so nothing of the project is shared between jobs.

What a fork cannot give a job falls back to a fresh interpreter (``subprocess.run``, unchanged):
a command that is not ``sys.executable -m MODULE``, ``sys.executable SCRIPT.py`` or this environment's
``aslexp`` (run as ``-m aslexp.cli``, what the console script calls), an environment whose variables read at import
(``_IMPORT_TIME_ENV``) differ from the pre-importer's, stdin or stdout other than a capture, a file or
nothing. ``ASLEXP_TEST_FRESH_PROCESSES=1`` runs every job in a fresh interpreter (the behaviour before;
also what a job's own tests of import cost and ``--help`` speed use: tests/platform/test_cli_habits.py).
"""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

# The libraries a job imports that take most of its start (measured with -X importtime: torch 1.4 s,
# SciPy's stats and scikit-learn 1 s, Matplotlib 0.7 s, Hydra/OmegaConf/Optuna 0.5 s on this machine;
# tensordict and torchrl 1.3 s more, most of it torch's compiler, which tensordict imports: every imitate job).
# PyBullet is left out: it prints a banner on import, which a job's output shows or hides on purpose.
PRELOAD = ("numpy", "torch", "torch.nn", "torch.optim", "scipy.stats", "sklearn.linear_model", "sklearn.ensemble",
           "sklearn.metrics", "sklearn.model_selection", "sklearn.preprocessing", "pandas", "matplotlib",
           "matplotlib.pyplot", "hydra", "hydra.main", "hydra._internal.utils", "hydra.core.plugins", "omegaconf",
           "optuna", "gymnasium", "mujoco", "yaml", "PIL.Image", "tensordict", "torchrl.modules", "torchrl.objectives",
           "torchrl.objectives.value")
# Read by a library while it is imported: a job asking for other values needs a fresh interpreter.
_IMPORT_TIME_ENV = ("PYTHONPATH", "PYTHONHASHSEED", "PYTHONWARNINGS", "PYTHONOPTIMIZE", "PYTHONDONTWRITEBYTECODE",
                    "MPLBACKEND", "MPLCONFIGDIR", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                    "CUDA_VISIBLE_DEVICES", "MUJOCO_GL", "TORCH_HOME", "VIRTUAL_ENV", "PYTHONIOENCODING", "PYTHONUTF8",
                    "LANG", "LC_ALL", "LC_CTYPE")

_SERVER = r"""
import importlib, json, os, runpy, sys
for name in json.loads(sys.argv[1]):
    try:
        importlib.import_module(name)
    except Exception:
        pass  # a library this machine lacks: the job imports (or misses) it itself
import gc
gc.freeze()  # the imported objects stay out of every job's collections (no copy-on-write of the heap)
requests, replies = os.fdopen(int(sys.argv[2]), "r"), os.fdopen(int(sys.argv[3]), "w")
replies.write("ready\n"); replies.flush()
for line in requests:
    job = json.loads(line)
    pid = os.fork()
    if pid == 0:
        requests.close(); replies.close()
        os.setpgid(0, 0)  # its own process group: a timeout ends the job and what it started
        os.chdir(job["cwd"])
        os.environ.clear(); os.environ.update(job["env"])
        for fd, path, mode in ((0, job["stdin"], os.O_RDONLY), (1, job["stdout"], os.O_WRONLY),
                               (2, job["stderr"], os.O_WRONLY)):
            target = os.open(path, mode)
            os.dup2(target, fd); os.close(target)
        sys.stdin = sys.__stdin__ = open(0, "r", closefd=False)
        sys.argv = [job["module"] or job["script"], *job["args"]]
        if job["script"]:  # python SCRIPT: its folder first on the path, as a fresh interpreter's
            sys.path[0] = os.path.dirname(os.path.abspath(job["script"]))
        del job, line, requests, replies, pid
        try:
            if sys.argv[0].endswith(".py"):
                runpy.run_path(sys.argv[0], run_name="__main__")
            else:
                runpy.run_module(sys.argv[0], run_name="__main__", alter_sys=True)
            code = 0
        except SystemExit as stop:
            code = stop.code if isinstance(stop.code, int) else 0 if stop.code is None else 1
            if not isinstance(stop.code, (int, type(None))):
                print(stop.code, file=sys.stderr)
        except BaseException as error:  # the traceback from the job's own frames, not this loader's
            trace = error.__traceback__
            while trace is not None and trace.tb_frame.f_code.co_filename in ("<string>", "<frozen runpy>"):
                trace = trace.tb_next
            sys.excepthook(type(error), error.with_traceback(trace), trace)
            code = -2 if isinstance(error, KeyboardInterrupt) else 1
        # The interpreter's exit less its module teardown (2-3 s with torch loaded, which a job's
        # result never depends on): threads joined, atexit handlers (logging's flush among them),
        # garbage finalised, streams flushed.
        import atexit, gc, signal, threading
        threading._shutdown()
        atexit._run_exitfuncs()
        gc.collect()
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:
                pass
        if code == -2:
            signal.signal(signal.SIGINT, signal.SIG_DFL); os.kill(os.getpid(), signal.SIGINT)
        os._exit(code & 0xFF)
    replies.write(f"pid {pid}\n"); replies.flush()
    _, status = os.waitpid(pid, 0)
    replies.write(f"exit {os.waitstatus_to_exitcode(status)}\n"); replies.flush()
"""


class _Server:
    """One pre-importing interpreter per test process; one job at a time (others run fresh)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.env = {k: os.environ.get(k) for k in _IMPORT_TIME_ENV}
        to_server, requests = os.pipe()
        replies, from_server = os.pipe()
        self.proc = subprocess.Popen([sys.executable, "-c", _SERVER, json.dumps(PRELOAD), str(to_server),
                                      str(from_server)], pass_fds=(to_server, from_server),
                                     stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(to_server)
        os.close(from_server)
        self.requests = os.fdopen(requests, "w")
        self.replies = os.fdopen(replies, "r")
        self.started = False

    def reply(self, timeout: float | None) -> str | None:
        ready, _, _ = select.select([self.replies], [], [], timeout)
        if not ready:
            return None
        line = self.replies.readline()
        if not line:
            raise RuntimeError("tests/job_process.py: the pre-importing interpreter ended")
        return line.strip()

    def alive(self) -> bool:
        if not self.started:
            self.started = self.reply(120) == "ready"
        return self.started and self.proc.poll() is None


_server: _Server | None = None


def _the_server() -> _Server | None:
    global _server
    if os.environ.get("ASLEXP_TEST_FRESH_PROCESSES") == "1":
        return None
    if _server is None or _server.proc.poll() is not None:
        _server = _Server()
    return _server if _server.alive() else None


last_forked = False  # whether the last run() was a fork (tests/platform/test_job_process.py reads it)


def _note(how: str, command: list[str], why: str) -> None:
    """``ASLEXP_TEST_JOB_PROCESS_LOG=FILE``: one line per job, forked or fresh and why."""
    global last_forked
    last_forked = how == "forked"
    if os.environ.get("ASLEXP_TEST_JOB_PROCESS_LOG"):
        with open(os.environ["ASLEXP_TEST_JOB_PROCESS_LOG"], "a") as log:
            log.write(f"{how}\t{why}\t{' '.join(command)[:200]}\n")


def run(command: list[str], *, cwd: str | Path | None = None, env: dict | None = None, input: str | None = None,
        capture_output: bool = False, text: bool = False, timeout: float | None = None, check: bool = False,
        stdout=None, stderr=None) -> subprocess.CompletedProcess:
    """``subprocess.run(command, ...)`` for ``[sys.executable, "-m", MODULE, *ARGS]`` (or a script), in a fork of the
    pre-importing interpreter where that gives the job what a fresh one would (see the module's doc)."""
    kwargs = dict(cwd=cwd, env=env, input=input, capture_output=capture_output, text=text, timeout=timeout,
                  check=check, stdout=stdout, stderr=stderr)
    env_now = dict(os.environ if env is None else env)
    command = [str(word) for word in command]
    if command and command[0] == str(Path(sys.executable).parent / "aslexp"):  # the console script
        command = [sys.executable, "-m", "aslexp.cli", *command[1:]]
    script = len(command) >= 2 and command[1].endswith(".py") and not command[1].startswith("-")
    forkable = (len(command) >= 2 and command[0] == sys.executable and (command[1] == "-m" and len(command) >= 3 or script)
                and (capture_output or stdout in (None, subprocess.DEVNULL))
                and (capture_output or stderr in (None, subprocess.DEVNULL, subprocess.STDOUT)))
    if isinstance(input, str) and not text:
        raise TypeError("job_process.run: input is text; give text=True or bytes (as subprocess.run)")
    server = _the_server() if forkable else None
    differ = [k for k in _IMPORT_TIME_ENV if server is not None and env_now.get(k) != server.env[k]]
    if server is None or differ or not server.lock.acquire(blocking=False):
        _note("fresh", command, "not forkable" if not forkable else "no server" if server is None else
              f"environment differs: {differ}" if differ else "busy")
        return subprocess.run(command, **{k: v for k, v in kwargs.items() if v is not None and v is not False})
    _note("forked", command, "")
    try:
        return _run_forked(server, command, cwd, env_now, input, capture_output, text, timeout, check, stdout, stderr)
    finally:
        server.lock.release()


def _run_forked(server: _Server, command, cwd, env, input, capture_output, text, timeout, check, stdout, stderr):
    with tempfile.TemporaryDirectory(prefix="job_process_") as folder:
        files = {name: os.path.join(folder, name) for name in ("stdin", "stdout", "stderr")}
        Path(files["stdin"]).write_bytes(b"" if input is None else input.encode() if isinstance(input, str) else input)
        for name in ("stdout", "stderr"):
            Path(files[name]).touch()
        if stderr == subprocess.STDOUT:
            files["stderr"] = files["stdout"]
        if not capture_output:  # not captured: where this process's own output goes (pytest's capture)
            if stdout == subprocess.DEVNULL:
                files["stdout"] = os.devnull
            if stderr == subprocess.DEVNULL:
                files["stderr"] = os.devnull
        script = command[1] if command[1] != "-m" else None
        server.requests.write(json.dumps({"module": None if script else command[2], "script": script,
                                          "args": command[2 if script else 3:],
                                          "cwd": str(Path(cwd or os.getcwd()).resolve()), "env": env, **files}) + "\n")
        server.requests.flush()
        pid = int(server.reply(120).split()[1])
        started = time.monotonic()
        answer = server.reply(timeout)
        if answer is None:
            try:
                os.killpg(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            server.reply(60)
        code = int(answer.split()[1]) if answer else -signal.SIGKILL
        out = Path(files["stdout"]).read_bytes() if files["stdout"] != os.devnull else b""
        err = Path(files["stderr"]).read_bytes() if files["stderr"] not in (os.devnull, files["stdout"]) else b""
    if text:
        out, err = out.decode(errors="replace"), err.decode(errors="replace")
    if not capture_output:
        if stdout is None and out:
            sys.stdout.write(out if text else out.decode(errors="replace"))
        if stderr is None and err:
            sys.stderr.write(err if text else err.decode(errors="replace"))
        out = err = None
    elif stderr == subprocess.STDOUT:
        err = None
    if answer is None:
        raise subprocess.TimeoutExpired(command, timeout if timeout is not None else time.monotonic() - started,
                                        output=out, stderr=err)
    result = subprocess.CompletedProcess(command, code, out, err)
    if check:
        result.check_returncode()
    return result
