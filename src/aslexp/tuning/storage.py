"""Where a study lives, and a lock that makes the trial budget exact.

A storage spec is one string:

* a path (``/shared/sweeps/q/optuna.journal``): Optuna's journal file storage, safe for several
  processes and for several machines on one shared file system; the default is
  ``<sweep dir>/optuna.journal``;
* a database URL (``postgresql://user@host/db``, ``sqlite:///study.db``, ``mysql+pymysql://...``):
  Optuna's RDB storage. PostgreSQL serves many machines; SQLite suits one process only.

Passwords: prefer ``~/.pgpass`` or ``PGPASSWORD`` to a password in the URL; tools that write the
storage into files (sweep.json) strip the password with :func:`redact`. PostgreSQL needs the
driver: ``pip install 'aslexp[postgres]'``.

Every append to a journal file is all-or-nothing (:class:`AtomicJournalFileBackend`): a write
that comes back short or fails (a full disk, a file-size limit) is cut back to the last whole
record and retried for ``JOURNAL_FULL_DISK_WAIT`` seconds, then refused with one line naming the
file; a record is never glued onto a torn one. A torn last record (a writer killed mid-append)
is cut off by the next writer, under the write lock, after a backup copy and a warning naming the
file and the byte offset; the torn record was never acknowledged to anyone, so nothing that
happened is lost. Readers (``open_storage(spec, read_only=True)``: the sweep tools) write nothing,
take no lock and skip a torn tail. Damage inside the file is refused with the file, line and byte.

A trial whose own files (run folder, run.json, metrics, checkpoints) find the disk full pauses its
sweep the same way: :func:`wait_for_space` probes the trial's folder for the same
``JOURNAL_FULL_DISK_WAIT`` seconds, then :class:`DiskFullError` stops the sweep in one line.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import logging
import os
import random
import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit, urlunsplit

import optuna
from optuna.storages import BaseStorage, RDBStorage
from optuna.storages.journal import JournalFileBackend, JournalStorage
from optuna.storages.journal._file import BaseJournalFileLock  # not re-exported (optuna 4, 5)

log = logging.getLogger(__name__)

DEFAULT_JOURNAL = "optuna.journal"
# How long an append waits for a full disk (or a file-size limit) to clear before it gives up.
JOURNAL_FULL_DISK_WAIT = float(os.environ.get("ASLEXP_JOURNAL_FULL_DISK_WAIT", "120"))
_NO_SPACE = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


class StorageError(RuntimeError):
    """A storage that cannot be opened, with what was tried and why it failed."""


def is_database_url(spec: str) -> bool:
    return "://" in spec


def default_storage(sweep_dir: str | os.PathLike) -> str:
    return str(Path(sweep_dir).resolve() / DEFAULT_JOURNAL)


def resolve_spec(spec: str | None, sweep_dir: str | os.PathLike) -> str:
    """The storage spec to use: the default journal file, an absolute journal path, or a URL."""
    if spec is None or str(spec).strip() == "":
        return default_storage(sweep_dir)
    spec = str(spec).strip()
    if is_database_url(spec):
        return spec
    return str(Path(spec).expanduser().resolve())


def redact(spec: str) -> str:
    """The spec with any password removed (safe to write into files and logs)."""
    if not is_database_url(spec):
        return spec
    parts = urlsplit(spec)
    if parts.password is None:
        return spec
    netloc = parts.netloc.rsplit("@", 1)[1]
    user = parts.username or ""
    return urlunsplit(parts._replace(netloc=f"{user}@{netloc}" if user else netloc))


def open_storage(spec: str, retries: int = 5, read_only: bool = False) -> BaseStorage:
    """Open (creating if needed) the storage named by ``spec``.

    Several workers starting at once may race to create an RDB schema; that is retried.
    ``read_only``: a journal file is read without creating, repairing or locking anything (the
    sweep tools: a sweep on a read-only file system, or another user's, reads back).
    """
    if not is_database_url(spec):
        return _open_journal(Path(spec), read_only=read_only)
    if urlsplit(spec).scheme.startswith("postgresql"):
        _require_postgres_driver(spec)
    last: Exception | None = None
    for attempt in range(retries):
        try:
            return RDBStorage(spec, engine_kwargs={"pool_pre_ping": True})
        except ImportError as err:
            raise StorageError(
                f"storage {redact(spec)}: the database driver is missing ({err})"
            ) from err
        except Exception as err:  # noqa: BLE001 - SQLAlchemy/driver errors vary by backend
            last = err
            if "password" in str(err) or "authentication" in str(err):
                break  # retrying cannot fix credentials
            time.sleep(0.2 + random.random() * 0.5 * (attempt + 1))
    hint = ""
    if last is not None and ("password" in str(last) or "authentication" in str(last)):
        hint = " (give the password in ~/.pgpass, PGPASSWORD, or the URL via --storage)"
    raise StorageError(f"cannot open storage {redact(spec)}{hint}: {last}") from last


POSTGRES_EXTRA_HINT = "pip install 'aslexp[postgres]'"


def _require_postgres_driver(spec: str) -> None:
    """PostgreSQL storage needs psycopg (the ``postgres`` extra): say so in one line."""
    import importlib.util

    driver = urlsplit(spec).scheme.partition("+")[2] or "psycopg"
    module = {"psycopg": "psycopg", "psycopg2": "psycopg2", "asyncpg": "asyncpg",
              "pg8000": "pg8000"}.get(driver, driver)
    if importlib.util.find_spec(module) is None:
        raise StorageError(f"storage {redact(spec)} is PostgreSQL, whose driver {module} is not "
                           f"installed: {POSTGRES_EXTRA_HINT}")


def _open_journal(path: Path, read_only: bool = False) -> JournalStorage:
    """A journal file storage; a writer's journal gets its torn tail (if any) repaired first."""
    try:
        if read_only:
            if not path.is_file():
                raise StorageError(f"journal file {path} does not exist")
            backend: JournalFileBackend = ReadOnlyJournalFileBackend(str(path))
        else:
            lock = FlockJournalLock(path)
            path.parent.mkdir(parents=True, exist_ok=True)
            if path.exists():
                with _held(lock):
                    repair_torn_tail(path)
            backend = AtomicJournalFileBackend(str(path), lock_obj=lock)
        try:
            return JournalStorage(backend)
        except (ValueError, UnicodeDecodeError) as err:  # JSONDecodeError is a ValueError
            raise StorageError(damage_report(path) or f"journal file {path} cannot be read: {err}") from None
    except OSError as err:
        raise StorageError(f"cannot open journal file {path}: {err}") from err


class JournalWriteError(StorageError):
    """A journal record that could not be written; the file was left at its last whole record."""


class DiskFullError(JournalWriteError):
    """A trial's own files found the disk full, and no space came back within the wait.

    A :class:`JournalWriteError` so that the sweeper stops on it the same way: one line, exit 1.
    """


# Free bytes a trial's folder must take again before a sweep paused by a full disk goes on.
SPACE_PROBE_BYTES = 1 << 20


def has_space(folder: str | os.PathLike, size: int = SPACE_PROBE_BYTES) -> bool:
    """Whether ``size`` bytes can be written in ``folder`` now: a probe file, written, synced and
    removed at once. A quota counts as well as a full device; any other error is not a full disk
    (not one to wait for), so it says True."""
    probe = Path(folder) / f".aslexp-space-probe-{os.getpid()}"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    except OSError as err:
        return err.errno not in _NO_SPACE
    try:
        block, left = b"\0" * min(size, 1 << 16), size
        while left > 0:
            written = os.write(fd, block[:left])
            if written <= 0:
                return False
            left -= written
        os.fsync(fd)  # a network file system may report a full disk only here
        return True
    except OSError as err:
        return err.errno not in _NO_SPACE
    finally:
        os.close(fd)
        probe.unlink(missing_ok=True)


def wait_for_space(folder: str | os.PathLike, deadline: float) -> bool:
    """Wait until :func:`has_space` in ``folder`` or ``time.monotonic()`` passes ``deadline``,
    with the journal appends' backoff (0.1 s doubling to 5 s); whether space came back."""
    delay = 0.1
    while True:
        if has_space(folder):
            return True
        left = deadline - time.monotonic()
        if left <= 0:
            return False
        time.sleep(min(delay, left))
        delay = min(delay * 2, 5.0)


class AtomicJournalFileBackend(JournalFileBackend):
    """Optuna's journal file backend with all-or-nothing appends.

    Optuna appends with one buffered ``write``: on a full disk part of a record can land, the
    error is swallowed by a heartbeat thread, and the next record is glued onto the torn one
    (every later reader then refuses the file). Here, under the write lock: a torn tail left by a
    killed writer is cut off first; the records are written with ``os.write`` until every byte is
    down and fsynced; on any error the file is truncated back to where it was. A full disk (or a
    file-size limit) is retried with backoff for ``full_disk_wait`` seconds, so a brief one costs a
    pause, not the study; after that the error names the file and says nothing was written.
    """

    def __init__(self, file_path: str, lock_obj: BaseJournalFileLock | None = None,
                 full_disk_wait: float | None = None) -> None:
        super().__init__(file_path, lock_obj=lock_obj)
        self.full_disk_wait = JOURNAL_FULL_DISK_WAIT if full_disk_wait is None else full_disk_wait

    def append_logs(self, logs: list[dict[str, Any]]) -> None:
        data = ("\n".join(json.dumps(r, separators=(",", ":")) for r in logs) + "\n").encode("utf-8")
        path = Path(self._file_path)
        deadline = time.monotonic() + self.full_disk_wait
        delay, warned = 0.1, False
        with _held(self._lock):
            while True:
                try:
                    _append_whole(path, data)
                    if warned:
                        log.warning("%s: written again after the full disk cleared", path)
                    return
                except OSError as err:
                    full = err.errno in _NO_SPACE
                    if not full or time.monotonic() + delay > deadline:
                        what = "the disk is full" if full else str(err)
                        raise JournalWriteError(
                            f"journal file {path}: {what}; the record was not written and the file "
                            "ends at its last whole record (free space, then resume the sweep)"
                        ) from err
                    if not warned:
                        log.warning("%s: the disk is full (%s); the record was cut back and is "
                                    "retried for up to %.0f s", path, err.strerror,
                                    self.full_disk_wait)
                        warned = True
                    time.sleep(delay)
                    delay = min(delay * 2, 5.0)


def _append_whole(path: Path, data: bytes) -> None:
    """Append ``data`` entirely or not at all (call with the journal's write lock held)."""
    if path.stat().st_size:
        repair_torn_tail(path)  # a writer killed mid-append: never glue a record onto it
    fd = os.open(path, os.O_WRONLY | os.O_APPEND)
    try:
        start = os.fstat(fd).st_size
        try:
            view = memoryview(data)
            while view:
                written = os.write(fd, view)
                if written <= 0:
                    raise OSError(errno.ENOSPC, "short write", str(path))
                view = view[written:]
            os.fsync(fd)
        except BaseException:
            os.ftruncate(fd, start)  # frees what landed: the file ends at its last whole record
            raise
    finally:
        os.close(fd)


class ReadOnlyJournalFileBackend(JournalFileBackend):
    """Reads a journal file and never writes: no file created, no lock taken.

    A torn last record (a writer died mid-append) is skipped by Optuna's reader; the next writer
    cuts it off.
    """

    def __init__(self, file_path: str) -> None:
        self._file_path = file_path
        self._lock = None  # type: ignore[assignment]
        self._log_number_offset = {0: 0}
        with open(file_path, "rb") as fh:
            size = fh.seek(0, os.SEEK_END)
            if size and (fh.seek(size - 1), fh.read(1))[1] != b"\n":
                log.warning("%s: the last record is torn (a writer died mid-append); it is skipped "
                            "here and cut off by the sweep's next writer", file_path)

    def append_logs(self, logs: list[dict[str, Any]]) -> None:
        raise StorageError(f"journal file {self._file_path} was opened read-only")


@contextlib.contextmanager
def _held(lock: BaseJournalFileLock) -> Iterator[None]:
    lock.acquire()
    try:
        yield
    finally:
        lock.release()


def repair_torn_tail(path: Path) -> int | None:
    """Cut a torn last record off a journal file (call with the journal's write lock held).

    Optuna appends one JSON record per line; a file that does not end in a newline holds a
    record whose writer died mid-write. It is cut off after a backup copy (``<file>.torn-<time>``)
    and a warning naming the file and the byte offset. Returns that offset, None if intact.
    """
    size = path.stat().st_size
    if size == 0:
        return None
    with open(path, "rb") as fh:
        fh.seek(size - 1)
        if fh.read(1) == b"\n":
            return None
        # Find the end of the last complete record.
        offset, block = size, 1 << 16
        while offset > 0:
            start = max(0, offset - block)
            fh.seek(start)
            chunk = fh.read(offset - start)
            newline = chunk.rfind(b"\n")
            if newline >= 0:
                offset = start + newline + 1
                break
            offset = start
    backup = path.with_name(f"{path.name}.torn-{time.strftime('%Y%m%d-%H%M%S')}")
    shutil.copy2(path, backup)
    with open(path, "r+b") as fh:
        fh.truncate(offset)
        fh.flush()
        os.fsync(fh.fileno())
    log.warning("%s: the last record was torn (%d bytes from byte %d, no newline: a writer died "
                "mid-append); cut off, the file as it was is kept in %s", path, size - offset,
                offset, backup)
    return offset


def damage_report(path: Path) -> str | None:
    """Where a journal file is damaged inside (first unreadable line), or None."""
    offset = 0
    with open(path, "rb") as fh:
        for number, line in enumerate(fh, start=1):
            try:
                json.loads(line)
            except ValueError as err:
                return (f"journal file {path} is damaged at line {number} (byte {offset}): "
                        f"{err}; it cannot be repaired automatically: restore it from a backup, "
                        "or start a new sweep folder")
            offset += len(line)
    return None


class FlockJournalLock(BaseJournalFileLock):
    """Journal write lock held with ``flock``: the kernel drops it when its process dies.

    Optuna's default symlink lock survives a SIGKILL during a write and then stalls every other
    process for its 30 s grace period; a resumed sweep would start with that wait.
    """

    def __init__(self, journal_path: str | os.PathLike) -> None:
        self._path = Path(str(journal_path) + ".write-lock")
        self._handle: Any = None
        self._thread_lock = threading.Lock()

    def acquire(self) -> bool:
        self._thread_lock.acquire()
        try:
            handle = open(self._path, "a")
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX)
        except BaseException:
            self._thread_lock.release()
            raise
        self._handle = handle
        return True

    def release(self) -> None:
        handle, self._handle = self._handle, None
        try:
            if handle is not None:
                fcntl.flock(handle.fileno(), fcntl.LOCK_UN)
                handle.close()
        finally:
            self._thread_lock.release()


def _lock_key(name: str) -> int:
    """A signed 64-bit advisory-lock key for PostgreSQL, stable across processes."""
    digest = hashlib.blake2b(name.encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big", signed=True)


@contextlib.contextmanager
def budget_lock(spec: str, study_name: str) -> Iterator[None]:
    """Serialise "count trials, then ask for one" across every worker of a study.

    Journal files and SQLite: an exclusive ``flock`` on a sidecar file next to the storage file
    (shared file systems must support ``flock``, as NFSv4 and Lustre do). PostgreSQL: a
    session advisory lock keyed on the study name. Other databases get no lock (documented in
    docs/sweeps.md: the budget may then be exceeded by at most workers - 1 trials).
    """
    if not is_database_url(spec):
        with file_lock(Path(spec).with_name(Path(spec).name + ".budget-lock")):
            yield
        return
    scheme = urlsplit(spec).scheme
    if scheme.startswith("sqlite"):
        # sqlite:///relative.db and sqlite:////absolute.db: drop exactly one leading slash.
        db_path = urlsplit(spec).path[1:]
        with file_lock(Path(db_path + ".budget-lock") if db_path and db_path != ":memory:" else None):
            yield
        return
    if scheme.startswith("postgresql"):
        with _pg_advisory_lock(spec, _lock_key(f"aslexp-budget:{study_name}")):
            yield
        return
    yield


@contextlib.contextmanager
def file_lock(path: Path | None) -> Iterator[None]:
    """An exclusive ``flock`` on ``path`` (created if needed); the kernel drops it on death."""
    if path is None:  # in-memory SQLite: one process, nothing to serialise
        yield
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as handle:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle.fileno(), fcntl.LOCK_UN)


_PG_ENGINES: dict[str, object] = {}


@contextlib.contextmanager
def _pg_advisory_lock(url: str, key: int) -> Iterator[None]:
    import sqlalchemy

    engine = _PG_ENGINES.get(url)
    if engine is None:
        # One pooled connection, kept open: a fresh connection per trial would cost a login.
        engine = sqlalchemy.create_engine(url, pool_size=1, max_overflow=1, pool_pre_ping=True)
        _PG_ENGINES[url] = engine
    with engine.connect() as conn:  # type: ignore[attr-defined]
        conn.execute(sqlalchemy.text("SELECT pg_advisory_lock(:key)"), {"key": key})
        try:
            yield
        finally:
            conn.execute(sqlalchemy.text("SELECT pg_advisory_unlock(:key)"), {"key": key})


def study_names(storage: BaseStorage) -> list[str]:
    return [s.study_name for s in storage.get_all_studies()]


def silence_optuna() -> None:
    """Keep Optuna's per-trial INFO lines out of sweep logs (the sweeper logs its own)."""
    optuna.logging.set_verbosity(optuna.logging.WARNING)
