"""A documented ``aslexp`` command line as (job, overrides): what the results page's catalogue holds."""

from __future__ import annotations

import shlex


def command_overrides(command: str) -> tuple[str, list[str]]:
    """(job, overrides) of ``aslexp JOB [-m] OVERRIDE...`` (shell words; ``-m`` dropped)."""
    words = shlex.split(command)
    if len(words) < 2 or words[0] != "aslexp":
        raise ValueError(f"not an aslexp command: {command!r}")
    return words[1], [w for w in words[2:] if w not in ("-m", "--multirun")]
