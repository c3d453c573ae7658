"""Where aslexp's configuration lives: one place for every layer (a leaf module).

A clone keeps ``conf/`` and ``sweeps/`` at the top of the repository, where users edit them;
``src/aslexp/_conf`` links there, and a wheel carries a copy of both under ``aslexp/_conf``
(package data), so an installed aslexp composes its jobs and finds its bodies without a clone.
"""

from __future__ import annotations

from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent
# A clone: <repo>/conf through the link; an installed wheel: the packaged copy.
CONF_DIR = (PACKAGE_DIR / "_conf").resolve()
# Search spaces (``+sweeps=NAME``): conf/sweeps, itself a link to the top-level sweeps/ in a clone.
SWEEPS_DIR = (CONF_DIR / "sweeps").resolve()
