"""Search spaces in Hydra's override grammar -> Optuna distributions, and values back to overrides."""

from __future__ import annotations

import pytest
from hydra.core.override_parser.overrides_parser import OverridesParser
from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution

from hydra_plugins.aslexp_optuna_sweeper._space import (
    SearchSpaceError,
    format_value,
    parse_search_space,
    quote,
)


def test_every_grammar_form_becomes_the_right_distribution() -> None:
    space = parse_search_space(
        {"x": "interval(-1, 1)", "lr": "tag(log, interval(1e-5, 1e-1))",
         "units": "int(interval(16, 256))", "wide": "tag(log, int(interval(16, 256)))",
         "layers": "range(1, 5)", "model": "choice(mlp, lstm)", "seed": 3},
        ["+sweeps=quadratic", "batch=32,64"],
    )
    d = space.distributions
    assert d["x"] == FloatDistribution(-1.0, 1.0)
    assert d["lr"] == FloatDistribution(1e-5, 1e-1, log=True)
    assert d["units"] == IntDistribution(16, 256)
    assert d["wide"] == IntDistribution(16, 256, log=True)
    assert d["layers"] == IntDistribution(1, 4)  # Hydra's range excludes its stop
    assert d["model"] == CategoricalDistribution(("mlp", "lstm"))
    assert d["batch"] == CategoricalDistribution((32, 64))
    assert space.fixed == ["seed=3", "+sweeps=quadratic"]


def test_command_line_sweep_replaces_the_params_entry_and_keeps_its_prefix() -> None:
    space = parse_search_space({"x": "interval(0, 1)"}, ["x=interval(0, 2)", "+extra=choice(a, b)"])
    assert space.distributions["x"] == FloatDistribution(0.0, 2.0)
    assert space.overrides_for({"x": 0.5, "extra": "a"}) == ["x=0.5", "+extra=a"]


@pytest.mark.parametrize("value", [0.1, 1e-05, -3.25e17, 7, True, None, "mlp", "a b", "it's",
                                   "C:\\path\\", "x,y", "null", "1.5"])
def test_formatted_values_parse_back_exactly(value) -> None:
    parsed = OverridesParser.create().parse_override(f"k={format_value(value)}").value()
    assert parsed == value and type(parsed) is type(value)


def test_quoted_json_survives_the_override_grammar() -> None:
    text = '{"storage":"postgresql://u:p@127.0.0.1/db?x=1","a":"it\'s \\\\"}'
    assert OverridesParser.create().parse_override(f"k={quote(text)}").value() == text


@pytest.mark.parametrize("params, message", [
    ({"x": "interval(1, 0)"}, "x: interval(1.0, 0.0) has low > high"),
    ({"x": "tag(log, interval(0, 1))"}, "x: a log interval needs low > 0"),
    ({"x": "tag(step, interval(0, 1))"}, "unknown tag(s) ['step']"),
    ({"x": "interval(0,"}, "cannot parse 'x=interval(0,'"),
    ({"x": "choice(a, a)"}, "repeated values"),
])
def test_bad_search_spaces_name_the_parameter(params, message) -> None:
    with pytest.raises(SearchSpaceError, match=None) as err:
        parse_search_space(params, [])
    assert message in str(err.value) and "hydra.sweeper.params" in str(err.value)


def test_enqueued_points_must_name_swept_parameters() -> None:
    from hydra_plugins.aslexp_optuna_sweeper._impl import _enqueued_points

    space = parse_search_space({"tuning.kp": "interval(0, 1)", "tuning.kd": "interval(0, 1)"}, [])
    points = [{"tuning.kp": 0.22, "tuning.kd": 0.87}]
    assert _enqueued_points(points, space) == points
    with pytest.raises(SearchSpaceError, match=r"^hydra.sweeper.enqueue\[0\]: tuning.kq not swept \(swept: tuning.kd, tuning.kp\)$"):
        _enqueued_points([{"tuning.kq": 0.2}], space)
    with pytest.raises(SearchSpaceError, match=r"^hydra.sweeper.enqueue: expected a list"):
        _enqueued_points({"tuning.kp": 0.2}, space)
