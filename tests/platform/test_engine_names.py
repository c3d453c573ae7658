"""No engine is named above the engine seam: outside ``src/aslexp/sim/`` the code speaks of
"an engine", "the engine that batches", and what differs between engines is data (``conf/engine``:
each engine's own keys and ``report:``, what a results row says about it; ``conf/engine_agreement.yaml``:
the engine configurations the agreement table compares). Read from the source, nothing imported.
"""

from __future__ import annotations

import re
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "src" / "aslexp"
NAMES = re.compile(r"pybullet|mujoco", re.IGNORECASE)

# (file under src/aslexp, text of the line that may name one): each with why it stays.
ALLOWED = {
    # the distributions whose versions a run records: the engines' package names there
    ("runs/record.py", '"pybullet", "gymnasium", "torchrl", "tensordict",'),
    # a command a user types: the launcher's example names the engine option it is run with
    ("jobs/stacked.py", "aslexp imitate -m motion=A,B seed=0,1 engine=mujoco ppo=fast hydra/launcher=stacked"),
}


def engine_mentions() -> list[tuple[str, int, str]]:
    """(file, line number, line) of every engine name in src/aslexp outside sim/."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        relative = path.relative_to(PACKAGE).as_posix()
        if relative.startswith("sim/"):
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if NAMES.search(line):
                found.append((relative, number, line.strip()))
    return found


def test_no_engine_is_named_outside_the_engine_modules():
    found = [f"src/aslexp/{file}:{number}: {line}" for file, number, line in engine_mentions()
             if not any(file == allowed_file and text in line for allowed_file, text in ALLOWED)]
    assert not found, ("engine names outside src/aslexp/sim/ (say 'the engine' or make it data in conf/engine; "
                       "or allow the line in ALLOWED with its reason):\n" + "\n".join(found))


def test_every_allowed_line_is_still_there():
    """An allowance whose line has gone is dropped from ALLOWED, so the list stays short and true."""
    mentions = engine_mentions()
    stale = [(file, text) for file, text in ALLOWED
             if not any(found == file and text in line for found, _, line in mentions)]
    assert not stale, f"allowed lines that no longer name an engine (remove them from ALLOWED): {stale}"


def test_what_a_row_says_about_an_engine_is_its_yamls_report():
    """A results row's engine sentence comes from ``report:`` (conf/engine/<name>.yaml), filled from the
    run's engine section; an engine without one (the tests') is said by its name."""
    from aslexp.compose import group
    from aslexp.results.differences import engine_text

    for name in ("pybullet", "mujoco"):
        assert "report" in group("engine", name), f"conf/engine/{name}.yaml has no report:"
    sentence = {"text": "Replay{lagging}", "parts": {"lagging": {"by": "lag", "0.0": "", "otherwise": " lagging {lag:g}"}}}
    assert engine_text({"engine": {"name": "replay", "lag": 0.0}}) == "replay"
    assert engine_text({"engine": {"name": "replay", "lag": 0.5, "report": sentence}}) == "Replay lagging 0.5"
    assert engine_text({"engine": {"name": "replay", "lag": 0.0, "report": sentence}}) == "Replay"
    # a run from before report: existed: today's file says it (here the default engine, no section at all)
    assert engine_text({}) == engine_text({"engine": group("engine")})


def test_report_is_a_key_every_engine_may_have():
    """``report:`` is declared once (aslexp.sim.engine.EngineSpec, beside name and module): an engine of
    the tests reads with or without it, and a malformed one is refused by name."""
    from dataclasses import dataclass

    import pytest

    from aslexp.errors import ConfigError
    from aslexp.sim import engine as engines

    @dataclass(frozen=True)
    class LagOptions:
        lag: float = 0.0

    engines.register_engine("names_test", options=LagOptions)(lambda spec, request: None)
    try:
        assert engines.EngineSpec.parse({"name": "names_test", "lag": 0.5}).report is None
        spec = engines.EngineSpec.parse({"name": "names_test", "lag": 0.5, "report": {"text": "Lagging"}})
        assert spec.report.text == "Lagging" and spec.options.lag == 0.5
        assert spec == engines.EngineSpec.parse({"name": "names_test", "lag": 0.5})  # nothing simulated reads it
        with pytest.raises(ConfigError, match=r"engine.report.parts.x: expected a `by:`"):
            engines.EngineSpec.parse({"name": "names_test", "report": {"text": "{x}", "parts": {"x": {"a": "b"}}}})
        with pytest.raises(ConfigError, match=r"engine.report: missing engine.report.text"):
            engines.EngineSpec.parse({"name": "names_test", "report": {}})
    finally:
        engines.unregister_engine("names_test")
