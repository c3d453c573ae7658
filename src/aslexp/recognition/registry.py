"""The classifier registry: a classifier is a registration, not a patch (as a keypoint format is).

A classifier is a builder, its accepted parameters with their defaults, and a YAML. A plugin
declares its parameters where it registers (the YAML it ships gives a run's values)::

    from aslexp.recognition.registry import register_classifier

    @register_classifier("tiny_mlp", {"hidden_size": 32}, summary="one hidden layer")
    def build(spec):                      # a ClassifierSpec: name, params, data shape, layout
        return torch.nn.Sequential(...)   # a torch module (trained by aslexp's trainer) or a Classifier

plus ``conf/classifier/tiny_mlp.yaml``::

    name: tiny_mlp
    module: my_package.tiny_mlp   # imported to register it (or an entry point of the group aslexp.classifiers)
    params: {hidden_size: 32}

``aslexp recognize classifier=tiny_mlp`` then trains, evaluates and reports it like a built-in. A
builder returning a ``torch.nn.Module`` called as ``module(x, mask)`` (clips ``(N, C, T, V)``, the
``(N, T, V)`` mask of observed joints) gets aslexp's trainer
(:class:`~aslexp.recognition.models.base.TorchClassifier`); one returning a
:class:`~aslexp.recognition.models.base.Classifier` is used as it is.

Names are known without importing torch: the built-ins are listed here, in the order reports show
them; their builders register when :mod:`aslexp.recognition.models` is imported. A built-in's
parameters and their defaults live once, in ``conf/classifier/NAME.yaml`` (its ``params``, read
through :mod:`aslexp.compose` as the job composes it): the builders declare none.
"""

from __future__ import annotations

import copy
import os
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from aslexp import compose
from aslexp.errors import ConfigError
from aslexp.plugins import import_registering_module, load_entry_points


ENTRY_POINT_GROUP = "aslexp.classifiers"
BUILT_IN_MODULE = "aslexp.recognition.models"
# The built-in classifiers in the order tables list them (chance baselines, feature models, then
# the sequence and graph networks).
BUILT_IN = ("majority", "stratified", "logreg", "svm", "rf", "hgb", "mlp", "lstm", "gru", "stgcn", "slgcn", "cnn3d")


@dataclass(frozen=True)
class ClassifierEntry:
    """A registered classifier: ``build(spec)`` returns a torch module or a Classifier;
    ``declared``: every parameter it accepts with its default, as the registration gave them
    (None: those of ``conf/classifier/NAME.yaml``, the built-ins' one place); ``baseline``: a
    chance baseline that every run reports beside the model (majority, stratified)."""

    name: str
    build: Callable[[Any], Any]
    declared: Mapping[str, Any] | None = None
    baseline: bool = False
    summary: str = ""

    @property
    def defaults(self) -> Mapping[str, Any]:
        """Every parameter it accepts, with its default."""
        return self.declared if self.declared is not None else conf_defaults(self.name)


def conf_defaults(name: str, conf_dir: str | os.PathLike | None = None) -> dict[str, Any]:
    """The ``params`` of ``conf/classifier/NAME.yaml`` as ``aslexp recognize classifier=NAME``
    composes them (cached by :mod:`aslexp.compose`; ``conf_dir``: another config tree)."""
    if conf_dir is None:
        compose.check_choice("classifier", name)  # a missing file is one line naming it
    classifier = compose.compose("recognize", [f"classifier={name}"], conf_dir=conf_dir)["classifier"]
    return dict(classifier.get("params") or {})


_CLASSIFIERS: dict[str, ClassifierEntry] = {}


def register_classifier(name: str, defaults: Mapping[str, Any] | None = None, *, baseline: bool = False,
                        summary: str = "", replace: bool = False):
    """Decorator: make ``build(spec)`` the classifier ``name`` with these parameter defaults
    (None: a built-in's are those of ``conf/classifier/NAME.yaml``; another's are none)."""

    def decorate(build: Callable[[Any], Any]):
        known = _CLASSIFIERS.get(name)
        if known is not None and known.build is not build and not replace:
            raise ConfigError(f"classifier {name!r} is already registered ({known.build.__module__}); "
                              "choose another name or pass replace=True")
        declared = dict(defaults) if defaults is not None else None if name in BUILT_IN else {}
        _CLASSIFIERS[name] = ClassifierEntry(name, build, declared, baseline, summary)
        return build

    return decorate


def unregister_classifier(name: str) -> None:
    """Forget a registered classifier (tests register throwaway ones)."""
    if name in BUILT_IN:
        raise ConfigError(f"classifier {name!r} is built in")
    _CLASSIFIERS.pop(name, None)


def _load_entry_points() -> None:
    load_entry_points(ENTRY_POINT_GROUP, "classifier")


def get_classifier(name: str, module: str | None = None) -> ClassifierEntry:
    """The classifier ``name``: built in, registered, registered by importing ``module`` (the
    classifier config's ``module`` key) or by an installed entry point."""
    if name not in _CLASSIFIERS:
        target = BUILT_IN_MODULE if name in BUILT_IN else module
        if target:
            import_registering_module("classifier", name, target)
        else:
            _load_entry_points()
    try:
        return _CLASSIFIERS[name]
    except KeyError:
        raise ValueError(f"unknown classifier {name!r}; known: {', '.join(classifier_names())} "
                         f"(or give classifier.module, the module that registers it)") from None


def check_classifier_name(name: str, module: str | None = None) -> None:
    """Refuse an unknown classifier before a job writes anything: one line listing the known ones
    (a ConfigError: exit 2). A built-in is known without importing torch; another name is looked up
    as :func:`get_classifier` does (``module``, the entry points)."""
    if name in BUILT_IN:
        return
    try:
        get_classifier(name, module)
    except ConfigError:
        raise  # a classifier.module that cannot be imported: already one line naming it
    except ValueError:
        raise ConfigError(f"classifier.name={name}: unknown classifier; expected one of "
                          f"{', '.join(classifier_names())} (or a classifier.module that registers it)") from None


def classifier_names() -> tuple[str, ...]:
    """Every known classifier: the built-ins in table order, then the registered ones."""
    _load_entry_points()
    return BUILT_IN + tuple(name for name in _CLASSIFIERS if name not in BUILT_IN)


def resolve_params(name: str, params: Mapping[str, Any] | None, module: str | None = None) -> dict[str, Any]:
    """Defaults of ``name`` updated with ``params``; unknown names or keys raise ValueError."""
    defaults = get_classifier(name, module).defaults
    params = dict(params or {})
    unknown = sorted(set(params) - set(defaults))
    if unknown:
        raise ValueError(f"classifier '{name}': unknown params {unknown}; accepted: {sorted(defaults) or 'none'}")
    resolved = copy.deepcopy(dict(defaults))
    resolved.update(params)
    return resolved


class DefaultParams(Mapping):
    """Every classifier's defaults by name, read from the registry (``DEFAULT_PARAMS[name]``)."""

    def __getitem__(self, name: str) -> Mapping[str, Any]:
        try:
            return get_classifier(name).defaults
        except ValueError:
            raise KeyError(name) from None

    def __iter__(self) -> Iterator[str]:
        return iter(classifier_names())

    def __len__(self) -> int:
        return len(classifier_names())
