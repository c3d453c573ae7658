"""Which process runs what: identities that survive pid reuse, and signals held off.

A run (run.json) and a sweep trial (the study's user attributes) record the identity of the
process running them: host, boot id, pid and the process' start time. Another process on the
same machine can then tell for sure that it is gone (killed, crashed, or a zombie not yet
reaped), even when the pid has been reused since; on another host only a heartbeat can tell.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import threading
from collections.abc import Iterator, Mapping
from typing import Any


def boot_id() -> str:
    try:
        with open("/proc/sys/kernel/random/boot_id", encoding="ascii") as fh:
            return fh.read().strip()
    except OSError:
        return ""


def _stat_fields(pid: int) -> list[str] | None:
    """Fields of /proc/PID/stat after the command name (state first), None if unreadable."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as fh:
            text = fh.read()
        return text.rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None


def process_start(pid: int) -> str | None:
    """Start time of a process in clock ticks since boot (Linux), to tell a reused pid apart."""
    fields = _stat_fields(pid)
    return fields[19] if fields and len(fields) > 19 else None


def process_identity(pid: int | None = None) -> dict[str, Any]:
    """``{"host", "boot", "pid", "start"}`` of this process (or of ``pid`` on this machine)."""
    pid = os.getpid() if pid is None else int(pid)
    return {"host": socket.gethostname(), "boot": boot_id(), "pid": pid,
            "start": process_start(pid)}


def process_is_gone(identity: Mapping[str, Any] | None) -> bool:
    """True only when ``identity`` ran on this very machine and its process no longer runs.

    A zombie (exited, not yet reaped by its parent) counts as gone: it runs nothing any more.
    Another host, or an identity without pid, is never judged here (False).
    """
    if not identity:
        return False
    if identity.get("host") != socket.gethostname() or identity.get("boot") != boot_id():
        return False
    pid = int(identity.get("pid") or -1)
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        pass  # exists, owned by someone else: judged by /proc below
    fields = _stat_fields(pid)
    if fields is None:
        return True
    if fields[0] in ("Z", "X"):  # zombie or dead: exited, only its parent has not reaped it
        return True
    start = fields[19] if len(fields) > 19 else None
    return identity.get("start") is not None and start is not None and start != identity["start"]


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, ``scancel``, a parent stopping its workers) as an exception, so that
    the run or trial it stops is recorded as interrupted on the way out."""


def raise_terminated(signum: int, frame: Any) -> None:
    """A SIGTERM handler: ``signal.signal(signal.SIGTERM, raise_terminated)``."""
    raise Terminated(f"signal {signal.Signals(signum).name}")


@contextlib.contextmanager
def sigterm_raises() -> Iterator[None]:
    """Inside the block (main thread only), SIGTERM raises :class:`Terminated`."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def slurm_context() -> dict[str, str] | None:
    """The Slurm job this process runs in (job id, array task, node), None outside Slurm."""
    keys = {"job_id": "SLURM_JOB_ID", "array_job_id": "SLURM_ARRAY_JOB_ID",
            "array_task_id": "SLURM_ARRAY_TASK_ID", "node": "SLURMD_NODENAME"}
    found = {name: os.environ[var] for name, var in keys.items() if os.environ.get(var)}
    return found or None


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """Ignore SIGINT and SIGTERM inside the block (main thread only).

    For the few lines that record an interruption: a second Ctrl-C, or the SIGTERM a parent
    sends to its workers, must not cut the bookkeeping of the first one in half.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, signal.SIG_IGN) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
