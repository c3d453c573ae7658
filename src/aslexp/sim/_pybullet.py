"""``from aslexp.sim._pybullet import pybullet``: PyBullet without its import banner.

PyBullet prints "pybullet build time: <date>" from C (fd 2) when its module loads; in every job
log and test output it is noise. Every aslexp module imports pybullet through here: the first
import runs with fd 2 pointed elsewhere (C writes are unbuffered, nothing else is lost: an
import error is still raised as a Python exception). URDF loading is quieted the same way
(:func:`c_output_quieted`).
"""

from __future__ import annotations

import os
import sys
import tempfile
from contextlib import contextmanager


@contextmanager
def c_output_quieted(streams: tuple[int, ...] = (2,)):
    """Points the file descriptors ``streams`` at a temporary file while the block runs: what
    PyBullet's C code writes there (its import banner; "b3Warning ... no axis element for Joint"
    for every spherical joint of a URDF, in every worker) is dropped when the block succeeds and
    written back to stderr when it raises, so a real failure keeps its C-side message."""
    try:
        sys.stdout.flush()
        sys.stderr.flush()
        saved = [os.dup(fd) for fd in streams]
    except (OSError, ValueError):  # no usable descriptors (embedded interpreters): run as is
        yield
        return
    with tempfile.TemporaryFile() as sink:
        for fd in streams:
            os.dup2(sink.fileno(), fd)
        try:
            yield
        except BaseException:
            _restore(streams, saved)
            sink.seek(0)
            text = sink.read().decode(errors="replace")
            if text:
                sys.stderr.write(text)
            raise
        else:
            _restore(streams, saved)


def _restore(streams: tuple[int, ...], saved: list[int]) -> None:
    for fd, copy in zip(streams, saved):
        if copy >= 0:
            os.dup2(copy, fd)
            os.close(copy)
    saved[:] = [-1] * len(saved)


def _import_quietly():
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    with c_output_quieted():
        import pybullet
    return pybullet


pybullet = _import_quietly()

__all__ = ["c_output_quieted", "pybullet"]
