"""The one composer: config group names become config dicts the way the jobs compose them.

Hydra composes every job's config at the edge (``aslexp.jobs``). Code below the edge that is given
a group by *name* (``gym.make(..., reward="hand_thesis")``, a baseline row's ``controller:
upper_body``, a test) asks this module, which composes the job's own config with Hydra's config
loader: the same defaults list, the same body groups (``body=upper_body`` brings its controller,
reward and env), the same ``ppo/base`` under a ``ppo=`` file. A default therefore lives once, in
``conf/``, and there is no second, Hydra-like reader of the YAML files.

Why a module of its own, low in the house, and not only the jobs: gymnasium users and the layers
below the jobs name groups too. The composition is pure (no global Hydra state is touched; it works
inside a running Hydra job and outside one) and cached; Hydra is imported on first use only, so
``import aslexp`` and ``aslexp --help`` stay free of it. It uses Hydra's ``ConfigLoaderImpl`` (public
since 1.0, under ``_internal``; ``hydra-core`` is pinned to 1.3) rather than ``hydra.compose``, whose
global ``initialize`` cannot nest inside a running job.

A leaf room: it imports nothing of aslexp but :mod:`aslexp.paths` and :mod:`aslexp.errors`.
"""

from __future__ import annotations

import copy
import functools
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from aslexp.errors import ConfigError
from aslexp.paths import CONF_DIR

IMITATE = "imitate"  # the job whose groups the imitation wing names (conf/imitate.yaml)


@functools.lru_cache(maxsize=4)
def _loader(conf_dir: str):
    from hydra import version
    from hydra._internal.config_loader_impl import ConfigLoaderImpl
    from hydra._internal.utils import create_config_search_path

    version.setbase("1.3")  # the jobs' version_base (aslexp.jobs._common), not Hydra's 1.1 fallback
    return ConfigLoaderImpl(config_search_path=create_config_search_path(conf_dir))


@functools.lru_cache(maxsize=256)
def _composed(job: str, overrides: tuple[str, ...], conf_dir: str = str(CONF_DIR),
              resolve: bool = True) -> tuple[dict[str, Any], dict[str, str]]:
    from hydra.errors import HydraException
    from hydra.types import RunMode
    from omegaconf import OmegaConf, open_dict

    try:
        cfg = _loader(conf_dir).load_configuration(config_name=job, overrides=list(overrides), run_mode=RunMode.RUN)
    except HydraException as error:
        first = str(error).strip().splitlines()[0]
        raise ConfigError(f"conf/{job}.yaml with {' '.join(overrides) or 'no overrides'}: {first}") from None
    choices = {str(k): str(v) for k, v in OmegaConf.to_container(cfg.hydra.runtime.choices).items()
               if v is not None and not str(k).startswith("hydra/")}
    with open_dict(cfg):
        del cfg["hydra"]
    return OmegaConf.to_container(cfg, resolve=resolve), choices


def compose(job: str = IMITATE, overrides: Sequence[str] = (), conf_dir: str | os.PathLike | None = None,
            resolve: bool = True) -> dict[str, Any]:
    """The job's whole config (``conf/<job>.yaml``) with these Hydra overrides, resolved, without
    the ``hydra`` node: exactly what the job itself would be given. ``conf_dir``: another config
    tree (a past commit's, to compare a run with the setting it ran under)."""
    where = str(Path(conf_dir).resolve()) if conf_dir is not None else str(CONF_DIR)
    return copy.deepcopy(_composed(job, tuple(overrides), where, resolve)[0])


def choices(job: str = IMITATE, overrides: Sequence[str] = ()) -> dict[str, str]:
    """Group -> chosen file of the composed job (``{"body": "hand15", "controller": "thesis", ...}``)."""
    return dict(_composed(job, tuple(overrides))[1])


def group(name: str, choice: str | None = None, job: str = IMITATE, overrides: Sequence[str] = ()) -> dict[str, Any]:
    """One group's config as the job composes it: ``conf/<name>/<choice>.yaml`` (None: the job's
    default, after ``overrides`` such as ``body=upper_body``), its defaults list applied."""
    if choice is not None:
        check_choice(name, choice)
        overrides = (*overrides, f"{name}={choice}")
    config = compose(job, overrides)
    if name not in config:
        raise ConfigError(f"conf/{job}.yaml has no group {name!r}")
    return config[name]


def check_choice(name: str, choice: str) -> None:
    """``conf/<name>/<choice>.yaml`` exists, else one line naming the group and what there is."""
    path = CONF_DIR / name / f"{choice}.yaml"
    if not path.is_file():
        available = sorted(p.stem for p in (CONF_DIR / name).glob("*.yaml"))
        raise ConfigError(f"{name}={choice}: no such config ({path}); available: {', '.join(available)}")


def body_groups(body: str, job: str = IMITATE) -> dict[str, str]:
    """The groups ``body=NAME`` brings (its file's ``override /GROUP`` defaults): controller, reward
    and env, as the job chooses them when nothing else names them."""
    chosen = choices(job, (f"body={body}",))
    return {key: chosen[key] for key in ("controller", "reward", "env") if key in chosen}


def deep_merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """``override`` over ``base`` (nested dicts merged, everything else replaced)."""
    out = copy.deepcopy(dict(base))
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), dict) and value:
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def resolve_group(name: str, value: str | Mapping[str, Any] | None, default: str | None = None,
                  job: str = IMITATE) -> dict[str, Any]:
    """A group's config from a file name, a partial dict merged over ``default`` (None: the job's
    default file), or None (``default``)."""
    if value is None or isinstance(value, str):
        return group(name, value if value is not None else default, job)
    if isinstance(value, Mapping):
        return deep_merge(group(name, default, job), value)
    raise TypeError(f"{name} config must be a name, a dict or None, got {type(value).__name__}")
