"""Typed, ranged configuration keys: one declaration per key, checked at the edge.

Every numeric (and a few other) key that a job reads is declared here once, with its type and
range or choices: :data:`PPO` (``conf/ppo/*.yaml``, read by :meth:`aslexp.rl.ppo.PPOConfig.parse`),
:data:`TRAINER` (``conf/trainer/*.yaml``, read by
:meth:`aslexp.recognition.train.TrainerConfig.parse`) and :data:`JOBS` (each job's keys,
sections included). The jobs check their composed config against :data:`JOBS` before anything
runs (:mod:`aslexp.jobs.validation`); the two readers coerce their section through the same
declarations, so a value is refused or accepted the same way wherever it comes from. What
depends on several keys or on the machine (``steps_per_rollout >= num_envs``, a CUDA device
that exists) stays with the readers (``PPOConfig.__post_init__``).

A refused value is a :class:`~aslexp.errors.ConfigError` naming the key, the value given and
what is expected, e.g. ``ppo.total_steps=abc: expected an integer >= 0``. Integers are never
rounded: ``4096.5`` and ``"abc"`` are refused, ``4096.0``, ``2e6`` and ``"4096"`` (an environment
variable) are read as integers.

A leaf module: it imports nothing of aslexp but :mod:`aslexp.errors`.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

from aslexp.errors import ConfigError


T = TypeVar("T")


class _Refused(Exception):
    """A value that does not fit its key (turned into a ConfigError naming the key)."""


@dataclass(frozen=True)
class Key:
    """One key's type (``int``, ``float``, ``bool``, ``str``, ``choice`` or ``list``) and range.

    ``low``/``high`` bound numbers (``low_open``/``high_open``: excluded; ``finite``: no infinity,
    which a number with one bound would otherwise take); ``choices`` lists the values of a
    ``choice``; ``item`` is a list's element; ``nullable`` accepts null.
    """

    kind: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] = ()
    item: Key | None = None
    nullable: bool = False
    nonempty: bool = False
    aliases: tuple[tuple[str, str], ...] = ()  # other spellings of a choice: (alias, choice)
    finite: bool = False

    # ------------------------------------------------------------------ what is expected

    def _range(self) -> str:
        low, high = self.low, self.high
        if low is not None and high is not None:
            return f" in {'(' if self.low_open else '['}{_num(low)}, {_num(high)}{')' if self.high_open else ']'}"
        if low is not None:
            return f" {'>' if self.low_open else '>='} {_num(low)}"
        if high is not None:
            return f" {'<' if self.high_open else '<='} {_num(high)}"
        return ""

    def expected(self, plural: bool = False) -> str:
        if self.kind == "int":
            if self.low == 1 and not self.low_open and self.high is None:
                text = "positive integers" if plural else "a positive integer"
            else:
                text = ("integers" if plural else "an integer") + self._range()
        elif self.kind == "float":
            noun = "finite number" if self.finite else "number"
            if self.low == 0 and self.low_open and self.high is None:
                text = f"positive {noun}s" if plural else f"a positive {noun}"
            else:
                text = (f"{noun}s" if plural else f"a {noun}") + self._range()
        elif self.kind == "bool":
            text = "true or false"
        elif self.kind == "choice":
            text = "one of " + ", ".join(self.choices)
        elif self.kind == "list":
            assert self.item is not None
            text = f"a {'non-empty ' if self.nonempty else ''}list of {self.item.expected(plural=True)}"
        else:
            text = "text" if plural else "a text"
        return f"null or {text}" if self.nullable else text

    # ------------------------------------------------------------------ coercion

    def coerce(self, value: Any) -> Any:
        """``value`` as this key's type; raises :class:`_Refused` if it does not fit."""
        if value is None:
            if self.nullable:
                return None
            raise _Refused
        if self.kind == "int":
            number = _integer(value)
        elif self.kind == "float":
            number = _number(value)
        elif self.kind == "bool":
            return _boolean(value)
        elif self.kind == "choice":
            if isinstance(value, (list, tuple, dict, bool)):
                raise _Refused
            text = dict(self.aliases).get(str(value), str(value))
            if text not in self.choices:
                raise _Refused
            return text
        elif self.kind == "list":
            if not isinstance(value, (list, tuple)) or (self.nonempty and not value):
                raise _Refused
            assert self.item is not None
            items = [self.item.coerce(v) for v in value]
            return items
        else:
            if isinstance(value, (list, tuple, dict)):
                raise _Refused
            return str(value)
        if self.finite and not math.isfinite(number):
            raise _Refused
        if self.low is not None and (number < self.low or (self.low_open and number == self.low)):
            raise _Refused
        if self.high is not None and (number > self.high or (self.high_open and number == self.high)):
            raise _Refused
        return number


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else repr(float(x))


def _integer(value: Any) -> int:
    if isinstance(value, bool):
        raise _Refused
    if isinstance(value, int):
        return value
    if isinstance(value, str):
        text = value.strip()
        try:
            return int(text)
        except ValueError:
            value = _number(text)
    if isinstance(value, float) and math.isfinite(value) and value.is_integer():
        return int(value)
    raise _Refused


def _number(value: Any) -> float:
    if isinstance(value, bool):
        raise _Refused
    if isinstance(value, (int, float)):
        number = float(value)
    elif isinstance(value, str):
        try:
            number = float(value.strip())
        except ValueError:
            raise _Refused from None
    else:
        raise _Refused
    if math.isnan(number):
        raise _Refused
    return number


def _boolean(value: Any) -> bool:
    if isinstance(value, bool):
        return value
    if isinstance(value, int) and value in (0, 1):
        return bool(value)
    if isinstance(value, str) and value.strip().lower() in ("true", "false"):
        return value.strip().lower() == "true"
    raise _Refused


def Int(low: int | None = None, high: int | None = None, *, nullable: bool = False) -> Key:  # noqa: N802
    return Key("int", low, high, nullable=nullable)


def Float(low: float | None = None, high: float | None = None, *, low_open: bool = False,  # noqa: N802
          high_open: bool = False, nullable: bool = False, finite: bool = False) -> Key:
    return Key("float", low, high, low_open, high_open, nullable=nullable, finite=finite)


def Positive(*, nullable: bool = False, finite: bool = False) -> Key:  # noqa: N802
    return Key("float", 0, None, low_open=True, nullable=nullable, finite=finite)


def Bool() -> Key:  # noqa: N802
    return Key("bool")


def Text(*, nullable: bool = False) -> Key:  # noqa: N802
    return Key("str", nullable=nullable)


def Choice(*values: str, aliases: Mapping[str, str] | None = None, nullable: bool = False) -> Key:  # noqa: N802
    return Key("choice", choices=tuple(values), aliases=tuple((aliases or {}).items()), nullable=nullable)


def List(item: Key, *, nonempty: bool = False, nullable: bool = False) -> Key:  # noqa: N802
    return Key("list", item=item, nonempty=nonempty, nullable=nullable)


def shown(value: Any) -> str:
    """A value as it was written on the command line (``abc``, ``4096.5``, ``null``, ``[1, 2]``)."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(shown(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k}: {shown(v)}" for k, v in value.items()) + "}"
    return str(value)


def check_value(path: str, value: Any, key: Key) -> Any:
    """``value`` coerced to ``key``'s type, or a ConfigError naming ``path``, the value and the rule."""
    try:
        return key.coerce(value)
    except _Refused:
        raise ConfigError(f"{path}={shown(value)}: expected {key.expected()}") from None


def check_section(section: str, values: Mapping[str, Any], schema: Mapping[str, Key],
                  unknown: bool = True) -> dict[str, Any]:
    """Every key of ``values`` checked and coerced against ``schema`` (keys absent from ``values``
    are left to their defaults). ``unknown``: a key the schema does not declare is refused."""
    out: dict[str, Any] = {}
    for name, value in values.items():
        key = schema.get(name)
        if key is None:
            if unknown:
                near = difflib.get_close_matches(name, list(schema), n=1)
                hint = f"; did you mean {section}.{near[0]}?" if near else f"; expected one of {', '.join(schema)}"
                raise ConfigError(f"{section}.{name}={shown(value)}: unknown key{hint}")
            out[name] = value
            continue
        out[name] = check_value(f"{section}.{name}", value, key)
    return out


# ---------------------------------------------------------------------------- the one reader

class Section:
    """A dataclass read from a config section by :func:`read`: ``Spec.parse(values)`` (``SECTION``
    names the section in errors: ``controller.mode=foo: expected one of position, stable_pd``)."""

    SECTION: typing.ClassVar[str] = "config"

    @classmethod
    def parse(cls: type[T], values: Mapping[str, Any] | None, section: str | None = None) -> T:
        return read(cls, values, section or cls.SECTION)  # type: ignore[attr-defined]


def key(declared: Key) -> dict[str, Key]:
    """A dataclass field's declaration: ``field(default=..., metadata=key(Int(1)))`` (a mapping of
    sections whose entry names are fixed says so with ``metadata={"names": (...)}``)."""
    return {"key": declared}


def read(cls: type[T], values: Mapping[str, Any] | None, section: str,
         schema: Mapping[str, Key] | None = None) -> T:
    """The one reader of a config section into its dataclass ``cls``.

    Unknown keys are refused with the nearest known one; missing required keys are named; each value
    is checked against its declaration (``schema[name]``, else the field's ``metadata=key(...)``) or,
    undeclared, coerced by the field's type (numbers, lists as tuples, nested sections read by this
    same function, ``dict[str, Section]`` entries each read, an entry set to null dropped: an override
    switching it off). A nested section with a default instance is read as that default updated by the
    keys given, so a partial dict changes only what it names. What depends on several keys is checked
    by the class's ``__post_init__``; its ConfigError is given this section's name. Every error is a
    :class:`~aslexp.errors.ConfigError` naming ``section.key``, the value and what is expected.
    """
    if values is None:
        values = {}
    if not isinstance(values, Mapping):
        raise ConfigError(f"{section}={shown(values)}: expected a mapping of keys")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = [name for name in values if name not in fields]
    if unknown:
        name = unknown[0]
        near = difflib.get_close_matches(str(name), list(fields), n=1)
        hint = f"; did you mean {section}.{near[0]}?" if near else f"; expected one of {', '.join(fields)}"
        raise ConfigError(f"{section}.{name}={shown(values[name])}: unknown key{hint}")
    missing = [name for name, f in fields.items() if name not in values and f.default is dataclasses.MISSING
               and f.default_factory is dataclasses.MISSING]
    if missing:
        raise ConfigError(f"{section}: missing {', '.join(f'{section}.{name}' for name in missing)}")
    hints = _type_hints(cls)
    out: dict[str, Any] = {}
    for name, value in values.items():
        where = f"{section}.{name}"
        declared = (schema or {}).get(name) or fields[name].metadata.get("key")
        names = fields[name].metadata.get("names")  # a mapping whose entries have fixed names (fingers)
        if names and isinstance(value, Mapping) and any(k not in names for k in value):
            wrong = next(k for k in value if k not in names)
            raise ConfigError(f"{where}.{wrong}: unknown entry; expected one of {', '.join(names)}")
        if declared is not None:
            value = check_value(where, value, declared)
        out[name] = _typed(hints[name], value, where, _default(fields[name]))
    try:
        return cls(**out)
    except ConfigError as error:
        text = str(error)
        raise ConfigError(text if text.startswith(section) else f"{section}.{text}") from None


@functools.lru_cache(maxsize=None)
def _type_hints(cls: type) -> dict[str, Any]:
    """A section class's field types (its string annotations evaluated once, not at every read)."""
    return typing.get_type_hints(cls)


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None


def _typed(hint: Any, value: Any, where: str, default: Any = None) -> Any:
    """``value`` read as the type ``hint`` says (see :func:`read`)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        return _typed(options[0], value, where, default) if len(options) == 1 else value
    if dataclasses.is_dataclass(hint):
        if isinstance(value, hint):
            return value
        if dataclasses.is_dataclass(default) and isinstance(value, Mapping):
            value = {**{f.name: getattr(default, f.name) for f in dataclasses.fields(default) if f.init}, **value}
        return read(hint, value, where)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}={shown(value)}: expected a list")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_typed(args[0], v, f"{where}[{i}]") for i, v in enumerate(value))
        if args and len(args) != len(value):
            raise ConfigError(f"{where}={shown(value)}: expected a list of {len(args)} values")
        return tuple(_typed(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value))) if args else tuple(value)
    if origin is list:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}={shown(value)}: expected a list")
        return [_typed(args[0], v, f"{where}[{i}]") for i, v in enumerate(value)] if args else list(value)
    if origin is dict and len(args) == 2 and dataclasses.is_dataclass(args[1]):
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}={shown(value)}: expected a mapping of name -> {{...}}")
        out = dict(default) if isinstance(default, Mapping) else {}  # entries given update the default's
        for k, v in value.items():
            if v is None:
                out.pop(str(k), None)
            else:
                out[str(k)] = _typed(args[1], v, f"{where}.{k}", out.get(str(k)))
        return out
    if origin is dict:
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}={shown(value)}: expected a mapping")
        return {k: _typed(args[1], v, f"{where}.{k}") for k, v in value.items()} if args else dict(value)
    if hint is float:
        return check_value(where, value, Float())
    if hint is int:
        return check_value(where, value, Int())
    if hint is bool:
        return check_value(where, value, Bool())
    if hint is str:
        return check_value(where, value, Text())
    return value


# ---------------------------------------------------------------------------- the declarations

SEED = Int(0)
# aslexp.recognition.device.check_precision's spellings (Lightning's included)
_PRECISION_ALIASES = {alias + suffix: canonical for alias, canonical in (
    ("32", "32"), ("fp32", "32"), ("float32", "32"), ("bf16", "bf16"), ("bfloat16", "bf16"),
    ("fp16", "fp16"), ("16", "fp16"), ("float16", "fp16")) for suffix in ("", "-mixed")}
FRACTION = Float(0, 1)
# A PD gain (conf/controller groups, tune_pd's tuning.kp/kd): a negative or infinite one drives
# the joints away from their targets, or blows the simulation up, and still ends with a score.
GAIN = Float(0, finite=True)
MAX_FORCE = Positive(finite=True)

#: conf/ppo/base.yaml documents every key (aslexp.rl.ppo.PPOConfig reads them).
PPO: dict[str, Key] = {
    "name": Text(),
    "hidden_sizes": List(Int(1)),
    "actor_hidden_sizes": List(Int(1), nullable=True),
    "activation": Choice("relu", "tanh", "elu"),
    "ortho_init": Bool(),
    "log_std_init": Float(),
    "action_mapping": Choice("box", "sb3"),
    "noise_beta": Float(0),
    "noise_horizon": Int(2),
    "learning_rate": Float(0),  # 0: a frozen policy
    "learning_rate_final": Float(0, nullable=True),
    "log_std_final": Float(nullable=True),
    "steps_per_rollout": Int(1),
    "minibatch_size": Int(1),
    "epochs": Int(1),
    "gamma": FRACTION,
    "gae_lambda": FRACTION,
    "clip_epsilon": Positive(),
    "entropy_coef": Float(0),
    "value_coef": Float(0),
    "max_grad_norm": Positive(),
    "target_kl": Positive(nullable=True),
    "kl_stop": Choice("torchrl", "sb3"),
    "weight_decay": Float(0),
    "critic_warmup_steps": Int(0),
    "total_steps": Int(0),  # 0: baselines and plots only
    "max_minutes": Float(0, nullable=True),  # 0: one rollout, then stop
    "target_reward": Float(nullable=True),
    "eval_interval": Int(1),
    "eval_steps": Int(1),
    "eval_episodes": Int(1),
    "eval_phases": List(Float(0, 1, high_open=True), nonempty=True, nullable=True),
    "eval_last_k": Int(1),
    "eval_at_start": Bool(),
    "num_envs": Int(1),
    "vector_env": Choice("auto", "sync", "async", "workers", "batched"),
    "batched_workers": Int(0),
    "device": Text(),
    "rollout_device": Choice("cpu", "learner"),
    "eval_device": Choice("cpu", "learner"),
    "torch_threads": Int(1),
    "progress_interval": Float(0),
}

#: conf/trainer/default.yaml documents every key (aslexp.recognition.train.TrainerConfig reads them).
TRAINER: dict[str, Key] = {
    "optimizer": Choice("adam", "sgd"),
    "lr": Float(0),  # 0: a frozen model
    "weight_decay": Float(0),
    "momentum": Float(0, 1),
    "nesterov": Bool(),
    "lr_schedule": Choice("step", "multistep", "none"),
    "lr_step_size": Int(1),
    "lr_gamma": Positive(),
    "lr_milestones": List(Int(0)),
    "warmup_epochs": Int(0),
    "batch_size": Int(1),
    "drop_last": Bool(),
    "max_epochs": Int(1),
    "early_stopping": Bool(),
    "patience": Int(1),
    "min_delta": Float(0),
    "selection_metric": Choice("mcc", "f1_micro", "f1_macro", "accuracy", "balanced_accuracy"),
    "retrain_epochs": Choice("best", "smoothed"),
    "smoothing_window": Int(1),
    "final_retrain": Bool(),
    "class_weights": Bool(),
    "crop_window": Int(0),
    "shift": Float(0),
    "shift_channels": List(Int(0)),
    "device": Text(),
    "precision": Choice("32", "bf16", "fp16", aliases=_PRECISION_ALIASES),
    "data_on_device": Bool(),
    "num_threads": Int(1),
    "deterministic": Bool(),
    "eval_batch_size": Int(1),
}

#: Per job: a dotted key and its Key, or a section name and its schema (every key of the section).
JOBS: dict[str, dict[str, Key | dict[str, Key]]] = {
    "imitate": {
        "seed": SEED,
        "ppo": PPO,
        "render.frames_every": Int(0),  # 0: no GIF frames
        "signing.read_back.enabled": Bool(),
        "signing.read_back.overrides": List(Text()),
    },
    "signing": {
        "seed": SEED,
        "signing.motions": Text(),
        "signing.limit": Int(1, nullable=True),
        "signing.implausible": Choice("skip", "keep"),
        "signing.held_out_only": Bool(),
        "signing.read_back.enabled": Bool(),
        "signing.read_back.overrides": List(Text()),
    },
    "recognize": {
        "seed": SEED,
        "n_seeds": Int(1),
        "trainer": TRAINER,
        "data.num_frames": Int(1),
        "data.padding": Choice("loop", "zero"),
        "split.seed": SEED,
        "split.repeats": Int(1),
        "split.val_fraction": Float(0, 1, low_open=True, high_open=True),
        "split.test_fraction": Float(0, 1, low_open=True, high_open=True),
        "split.num_folds": Int(2),
        "split.rare_classes": Choice("drop", "merge", "train_only"),
    },
    "tune_pd": {
        "seed": SEED,
        "tuning.steps": Int(1, nullable=True),
        "tuning.lookahead": Int(0),
        "tuning.objective": Choice("reward", "mean_abs", "thesis"),
        "tuning.kp": Float(0, nullable=True, finite=True),
        "tuning.kd": Float(0, nullable=True, finite=True),
        "tuning.max_force": Positive(nullable=True, finite=True),
        "tuning.velocity_scale": Float(nullable=True, finite=True),
        "tuning.random.seconds": Positive(),
        "tuning.random.keyframe_seconds": Positive(),
        "tuning.random.seed": SEED,
    },
}


@dataclass(frozen=True)
class Requirement:
    """A choice in one group that needs a value in another: when ``when(value of key)`` holds,
    ``needs`` must equal ``value`` (``because`` says why)."""

    key: str
    when: Any
    needs: str
    value: Any
    because: str


#: Per job: what one group's choice needs from another. All are checked together, against the
#: config with the fixes already found applied, so the first refusal names the whole fix.
REQUIREMENTS: dict[str, tuple[Requirement, ...]] = {
    "imitate": (
        Requirement("controller.target_rate", lambda v: v == "physics", "env.action_mode", "residual",
                    "re-samples the reference under the policy's correction, held over the control step"),
        Requirement("env.residual_base_smoothing", lambda v: isinstance(v, (int, float)) and v > 0,
                    "env.action_mode", "residual", "filters the base a correction is added to"),
        Requirement("env.action_mode", lambda v: v == "residual", "env.action_range", "joint",
                    "a correction's range is the joint's; action_range motion bounds absolute targets"),
    ),
}


def check_requirements(job: str, select) -> None:
    """Refuse a set of choices that needs more overrides, naming all of them at once."""
    fixes: dict[str, Any] = {}

    def value(path: str) -> Any:
        if path in fixes:
            return fixes[path]
        try:
            return select(path)
        except KeyError:
            return None

    reasons: list[str] = []
    changed = True
    while changed:  # a fix can need another (residual then needs action_range joint)
        changed = False
        for rule in REQUIREMENTS.get(job, ()):
            given = value(rule.key)
            if rule.when(given) and value(rule.needs) != rule.value:
                fixes[rule.needs] = rule.value
                group, _, key = rule.key.partition(".")
                chosen = f"{group} {value(group + '.name')}: {key}" if value(group + ".name") else rule.key
                reasons.append(f"{chosen}={shown(given)} needs {rule.needs}={shown(rule.value)} ({rule.because})")
                changed = True
    if fixes:
        add = " ".join(f"{key}={shown(v)}" for key, v in fixes.items())
        raise ConfigError(f"{'; '.join(reasons)}. Add: {add}")


def check_job(job: str, select) -> None:
    """Check ``job``'s keys; ``select(dotted_key)`` returns a key's resolved value (a section as a
    plain dict) or raises ``KeyError`` when the config has no such key. Jobs without a schema pass.
    Then what one group's choice needs from another (:data:`REQUIREMENTS`)."""
    for path, rule in JOBS.get(job, {}).items():
        try:
            value = select(path)
        except KeyError:
            continue
        if isinstance(rule, dict):
            if not isinstance(value, Mapping):
                raise ConfigError(f"{path}={shown(value)}: expected a config group (a mapping of keys)")
            check_section(path, value, rule)
        else:
            check_value(path, value, rule)
    check_requirements(job, select)
