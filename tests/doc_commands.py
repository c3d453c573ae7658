"""The command lines of a Markdown page's ```bash blocks, as the tests that run or check them read them."""

from __future__ import annotations

import re
from pathlib import Path


def bash_lines(path: Path) -> list[str]:
    """Every command line of ``path``'s ```bash blocks: continuations joined, comment lines and
    trailing ``  # ...`` comments dropped, runs of blanks made one."""
    out = []
    for block in re.findall(r"```bash\n(.*?)```", path.read_text(encoding="utf-8"), re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = re.split(r"\s+#\s", line.strip(), maxsplit=1)[0].strip()
            if line and not line.startswith("#"):
                out.append(re.sub(r"\s+", " ", line))
    return out


def override_variants(overrides: list[str]) -> list[list[str]]:
    """The configurations a multirun's command line asks for, enough to compose each value once:
    every swept override at its first value, then each further value of one sweep at a time."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parsed = OverridesParser.create().parse_overrides(overrides)
    swept = {o.input_line: [f"{o.get_key_element()}={v}" for v in o.sweep_string_iterator()]
             for o in parsed if o.is_sweep_override()}
    first = [swept[line][0] if line in swept else line for line in overrides]
    return [first] + [[value if line == sweep else chosen for line, chosen in zip(overrides, first)]
                      for sweep, values in swept.items() for value in values[1:]]
