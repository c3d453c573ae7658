"""``from aslexp.sim._pybullet import pybullet``: PyBullet without its import banner.

PyBullet prints "pybullet build time: <date>" from C (fd 2) when its module loads; in every job
log and test output it is noise. Every aslexp module imports pybullet through here: the first
import runs with fd 2 pointed at /dev/null (C writes are unbuffered, nothing else is lost: an
import error is still raised as a Python exception).
"""

from __future__ import annotations

import os
import sys


def _import_quietly():
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no usable fd 2 (embedded interpreters): import as is
        import pybullet

        return pybullet
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        import pybullet
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)
    return pybullet


pybullet = _import_quietly()

__all__ = ["pybullet"]
