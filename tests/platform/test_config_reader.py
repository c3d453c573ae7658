"""One composer (aslexp.compose) and one reader (aslexp.config_schema.read), on the real config tree."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from aslexp import compose
from aslexp.config_schema import Choice, Int, Section, key, read
from aslexp.errors import ConfigError


@dataclass(frozen=True)
class SmootherSpec(Section):  # docs/extending.md's example
    SECTION = "smoother"
    kind: str = field(default="ema", metadata=key(Choice("ema", "box")))
    window: int = field(default=4, metadata=key(Int(1)))


@dataclass(frozen=True)
class Outer(Section):
    SECTION = "outer"
    inner: SmootherSpec = field(default_factory=lambda: SmootherSpec(window=6))
    named: dict[str, SmootherSpec] = field(default_factory=lambda: {"a": SmootherSpec(), "b": SmootherSpec()})
    sizes: tuple[int, ...] = (1, 2)

    def __post_init__(self) -> None:
        if len(self.sizes) > 3:
            raise ConfigError(f"sizes={list(self.sizes)}: at most 3")


def test_the_documented_section_reads_and_refuses_in_one_line():
    assert SmootherSpec.parse({"window": 8}) == SmootherSpec("ema", 8)
    assert SmootherSpec.parse({"window": "8"}).window == 8  # an environment variable's text
    for values, message in (({"window": 0}, "smoother.window=0: expected a positive integer"),
                            ({"kind": "gauss"}, "smoother.kind=gauss: expected one of ema, box"),
                            ({"windwo": 3}, "smoother.windwo=3: unknown key; did you mean smoother.window?"),
                            ([1, 2], "smoother=[1, 2]: expected a mapping of keys")):
        with pytest.raises(ConfigError) as info:
            SmootherSpec.parse(values)
        assert str(info.value) == message


def test_nested_sections_change_only_what_they_name():
    outer = read(Outer, {"inner": {"kind": "box"}, "named": {"a": {"window": 9}, "b": None, "c": {}},
                         "sizes": [3, 4]}, "outer")
    assert outer.inner == SmootherSpec("box", 6)  # the default instance's window kept
    assert outer.named == {"a": SmootherSpec("ema", 9), "c": SmootherSpec()}  # null switches an entry off
    assert outer.sizes == (3, 4)
    with pytest.raises(ConfigError, match=r"^outer.named.a.window=-1: expected a positive integer$"):
        Outer.parse({"named": {"a": {"window": -1}}})
    with pytest.raises(ConfigError, match=r"^outer.sizes=\[1, 2, 3, 4\]: at most 3$"):  # __post_init__, named
        Outer.parse({"sizes": [1, 2, 3, 4]})


def test_group_names_compose_as_the_job_composes_them():
    # a body brings its groups; a group named beside it wins; ppo files sit over ppo/base
    assert compose.body_groups("upper_body") == {"controller": "upper_body", "reward": "upper_body_thesis",
                                                 "env": "upper_body"}
    chosen = compose.choices("imitate", ["body=upper_body", "controller=upper_body_thesis"])
    assert chosen["controller"] == "upper_body_thesis" and chosen["reward"] == "upper_body_thesis"
    ppo = compose.group("ppo", "hand_thesis")
    assert set(compose.group("ppo", "quick")) == set(ppo)  # every key of base.yaml under either file
    assert compose.group("motion", "A")["file"] == "motions/hand/A.txt"
    with pytest.raises(ConfigError, match=r"^reward=nope: no such config .*; available: deepmimic"):
        compose.group("reward", "nope")
    # a partial dict is merged over the group the job would choose
    merged = compose.resolve_group("env", {"control_hz": 60.0}, "hand_thesis")
    assert merged["control_hz"] == 60.0 and merged["physics_hz"] == compose.group("env", "hand_thesis")["physics_hz"]



@pytest.mark.parametrize("module, name, group, choice", [
    ("aslexp.rl.ppo", "PPOConfig", "ppo", "base"),
    ("aslexp.envs.spec", "EnvSpec", "env", "default"),
    ("aslexp.control.mpc", "PlannerSpec", "planner", "mpc"),
    ("aslexp.sim.mujoco_engine", "MujocoOptions", "engine", "mujoco"),
])
def test_a_default_written_in_code_too_is_the_yaml_s(module, name, group, choice):
    """The dataclasses keep defaults for Python users; the base file of each group is the job's. A
    value written in both places is the same value (the YAML's own comments document it)."""
    import dataclasses
    import importlib

    import yaml

    from aslexp.paths import CONF_DIR

    cls = getattr(importlib.import_module(module), name)
    written = yaml.safe_load((CONF_DIR / group / f"{choice}.yaml").read_text(encoding="utf-8"))
    written.pop("defaults", None)
    for f in dataclasses.fields(cls):
        if f.name not in written or f.name == "name" or str(written[f.name]).startswith("${"):
            continue  # a name, or an interpolation (the planner's seed is the run's)
        code = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        code = list(code) if isinstance(code, tuple) else code
        if isinstance(code, dict):
            assert {**code, **written[f.name]} == written[f.name], f"{name}.{f.name}"
        else:
            assert code == written[f.name], f"{name}.{f.name}: code {code!r}, conf/{group}/{choice}.yaml {written[f.name]!r}"
