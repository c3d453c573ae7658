"""Search spaces in Hydra's override grammar -> Optuna distributions, and back to overrides.

    x=interval(-1, 1)                      FloatDistribution(-1, 1)
    lr=tag(log, interval(1e-5, 1e-1))      FloatDistribution(1e-5, 1e-1, log=True)
    units=int(interval(16, 256))           IntDistribution(16, 256)
    units=tag(log, int(interval(16, 256))) IntDistribution(16, 256, log=True)
    layers=range(1, 5)                     IntDistribution(1, 4)          (stop excluded, as in Hydra)
    dropout=range(0, 0.5, 0.1)             FloatDistribution(0, 0.4, step=0.1)
    model=choice(mlp, lstm) | model=mlp,lstm   CategoricalDistribution(["mlp", "lstm"])
    seed=3                                 fixed: passed to every trial unchanged

Errors name the parameter and say what was expected, and are raised before any trial starts.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import (
    ChoiceSweep,
    IntervalSweep,
    Override,
    RangeSweep,
    Transformer,
)
from hydra.errors import HydraException
from optuna.distributions import (
    BaseDistribution,
    CategoricalDistribution,
    FloatDistribution,
    IntDistribution,
)


class SearchSpaceError(ValueError):
    """A search space that cannot be turned into Optuna distributions."""


@dataclass
class SearchSpace:
    """Distributions to sample, and the fixed overrides every trial gets verbatim."""

    distributions: dict[str, BaseDistribution] = field(default_factory=dict)
    fixed: list[str] = field(default_factory=list)
    # The override key as written (``+foo`` adds a key); keys of ``distributions`` are bare.
    prefixes: dict[str, str] = field(default_factory=dict)
    # The text each parameter was given as, for sweep.json and error messages.
    sources: dict[str, str] = field(default_factory=dict)

    def overrides_for(self, params: dict[str, Any]) -> list[str]:
        """The Hydra overrides of one trial: fixed ones, then each parameter's value."""
        items = [f"{self.prefixes.get(name, '')}{name}={format_value(value)}"
                 for name, value in params.items()]
        return [*self.fixed, *items]

    def sample_point(self) -> dict[str, Any]:
        """One valid point (low end / first choice), to check the config composes."""
        point: dict[str, Any] = {}
        for name, dist in self.distributions.items():
            if isinstance(dist, CategoricalDistribution):
                point[name] = dist.choices[0]
            else:
                point[name] = dist.low  # type: ignore[attr-defined]
        return point


_BARE_STRING = re.compile(r"^[A-Za-z_/][\w\-./:@]*$")
_RESERVED = {"true", "false", "null", "nan", "inf", "-inf", "True", "False", "None"}


def format_value(value: Any) -> str:
    """A value as a Hydra override value that parses back to exactly the same value."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)  # shortest text that round-trips
    text = str(value)
    if _BARE_STRING.match(text) and text not in _RESERVED:
        return text
    return quote(text)


def quote(text: str) -> str:
    """Single-quote a string for Hydra's override grammar.

    Hydra reads backslashes literally except in runs that precede a quote (or the closing
    quote), where they are escapes: double those runs, then escape the quotes.
    """
    doubled = re.sub(r"(\\+)(?='|$)", lambda run: run.group(1) * 2, text)
    return "'" + doubled.replace("'", "\\'") + "'"


def _distribution(override: Override) -> BaseDistribution:
    name = override.get_key_element()
    value = override.value()
    if isinstance(value, ChoiceSweep) or (isinstance(value, RangeSweep) and value.shuffle):
        choices = list(override.sweep_iterator(transformer=Transformer.encode))
        for choice in choices:
            if not isinstance(choice, (str, int, float, bool, type(None))):
                raise SearchSpaceError(
                    f"{name}: choice() values must be str, int, float, bool or null, "
                    f"got {choice!r} ({type(choice).__name__})"
                )
        if len(set(map(repr, choices))) != len(choices):
            raise SearchSpaceError(f"{name}: choice() has repeated values {choices}")
        return CategoricalDistribution(choices)
    if isinstance(value, RangeSweep):
        start, stop, step = value.start, value.stop, value.step
        if start is None or stop is None:
            raise SearchSpaceError(f"{name}: range() needs a start and a stop")
        items = list(override.sweep_iterator(transformer=Transformer.encode))
        if not items:
            raise SearchSpaceError(f"{name}: range({start}, {stop}, {step}) is empty")
        if all(isinstance(v, int) for v in (start, stop, step)):
            return IntDistribution(int(items[0]), int(items[-1]), step=int(step))
        return FloatDistribution(float(start), float(start) + float(step) * (len(items) - 1),
                                 step=float(step))
    if isinstance(value, IntervalSweep):
        start, end = value.start, value.end
        if start is None or end is None:
            raise SearchSpaceError(f"{name}: interval() needs a low and a high end")
        log = "log" in value.tags
        unknown = set(value.tags) - {"log"}
        if unknown:
            raise SearchSpaceError(f"{name}: unknown tag(s) {sorted(unknown)}; only 'log' is understood")
        if start > end:
            raise SearchSpaceError(f"{name}: interval({start}, {end}) has low > high")
        if log and start <= 0:
            raise SearchSpaceError(f"{name}: a log interval needs low > 0, got {start}")
        if isinstance(start, int) and isinstance(end, int):
            return IntDistribution(start, end, log=log)
        return FloatDistribution(float(start), float(end), log=log)
    raise SearchSpaceError(f"{name}: {override.input_line!r} is not a sweep Optuna can sample "
                           "(use choice, range, interval, tag(log, ...), int(...))")


def parse_search_space(params: dict[str, Any] | None, arguments: list[str]) -> SearchSpace:
    """Parse ``hydra.sweeper.params`` and the command-line task overrides into a SearchSpace.

    Command-line arguments that are sweeps join the search space (and win over ``params`` of the
    same name); the others are fixed overrides passed to every trial as written.
    """
    lines = [f"{key}={value}" for key, value in (params or {}).items()]
    origins = ["hydra.sweeper.params"] * len(lines) + ["command line"] * len(arguments)
    space = SearchSpace()
    parser = OverridesParser.create()
    for line, origin in zip([*lines, *arguments], origins):
        try:
            override = parser.parse_override(line)
        except HydraException as err:  # OverrideParseException and friends
            raise SearchSpaceError(f"{origin}: cannot parse {line!r}: {err}") from err
        if not override.is_sweep_override():
            if origin == "hydra.sweeper.params":
                key = override.get_key_element()
                space.fixed = [f for f in space.fixed if f.split("=", 1)[0] != key]
            space.fixed.append(line)
            continue
        key = override.get_key_element()
        bare = key.lstrip("+~")
        prefix = key[: len(key) - len(bare)]
        if prefix.startswith("~"):
            raise SearchSpaceError(f"{origin}: {line!r}: a deletion cannot be swept")
        try:
            space.distributions[bare] = _distribution(override)
        except SearchSpaceError as err:
            raise SearchSpaceError(f"{origin}: {err}") from err
        except (ValueError, TypeError) as err:  # Optuna's own checks of the distribution
            raise SearchSpaceError(f"{origin}: {bare}: {err}") from err
        space.prefixes[bare] = prefix
        space.sources[bare] = line.split("=", 1)[1]
        space.fixed = [f for f in space.fixed if f.split("=", 1)[0].lstrip("+~") != bare]
    return space
