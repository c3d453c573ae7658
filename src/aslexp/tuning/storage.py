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

A journal file whose last record was torn (a writer killed or a disk filled mid-append) is
repaired when it is opened: the file is backed up, the partial record cut off, and a warning
names the file and the byte offset. The torn record was never acknowledged to anyone, so nothing
that happened is lost. Damage inside the file is refused with the file, line and byte offset.
"""

from __future__ import annotations

import contextlib
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


def open_storage(spec: str, retries: int = 5) -> BaseStorage:
    """Open (creating if needed) the storage named by ``spec``.

    Several workers starting at once may race to create an RDB schema; that is retried.
    """
    if not is_database_url(spec):
        return _open_journal(Path(spec))
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


def _open_journal(path: Path) -> JournalStorage:
    """A journal file storage, its torn tail (if any) repaired first."""
    lock = FlockJournalLock(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.exists():
            with _held(lock):
                repair_torn_tail(path)
        try:
            return JournalStorage(JournalFileBackend(str(path), lock_obj=lock))
        except (ValueError, UnicodeDecodeError) as err:  # JSONDecodeError is a ValueError
            raise StorageError(damage_report(path) or f"journal file {path} cannot be read: {err}") from None
    except OSError as err:
        raise StorageError(f"cannot open journal file {path}: {err}") from err


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
