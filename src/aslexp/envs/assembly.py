"""One place that assembles an imitation experiment from its config groups.

An :class:`ImitationSetup` is everything an imitation experiment is before anything steps: the
motion and its reference, the body (URDF and motion layout), and the parsed controller, reward,
environment and engine settings. Every consumer builds from one: the environment
(``ImitationEnv.from_setup``; it only steps), a batch of environments (``BatchedImitationEnv.from_setup``),
the imitate job, the no-learning baselines (:meth:`ImitationSetup.merged`: a row's overrides over the
run's groups), the engine agreement report, and any controller that needs the simulation itself
(:meth:`ImitationSetup.simulation`, :meth:`ImitationSetup.pd_controller`,
:meth:`ImitationSetup.reward_function`).

Groups are names (``conf/<group>/<name>.yaml``), partial dicts merged over the group the imitate job
would choose, or complete dicts (``complete=True``: the jobs pass Hydra's composed groups, which merged
over another body's default file would gain its keys and reward terms). Names are composed by
:mod:`aslexp.compose` exactly as the job composes them (a body brings its controller, reward and env).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.compose import IMITATE, check_choice, compose, deep_merge, group, resolve_group
from aslexp.paths import CONF_DIR
from aslexp.envs.reward import ImitationReward, RewardSpec
from aslexp.envs.spec import EnvSpec
from aslexp.sim.body import BodyLayout, BodySpec, load_layout
from aslexp.sim.engine import EngineSpec, PhysicsConfig, Simulation, SimulationRequest, build_simulation
from aslexp.sim.motion import Motion, MotionFormatError, load_motion
from aslexp.sim.pd import ControllerSpec, PDController
from aslexp.sim.reference import ReferenceMotion

log = logging.getLogger(__name__)

GROUPS = ("body", "controller", "reward", "env", "engine")


@dataclass(frozen=True)
class ImitationSetup:
    """One imitation experiment, assembled (module docstring). ``groups``: the complete group dicts
    it was parsed from (what :meth:`merged` merges overrides over)."""

    motion: Motion
    groups: dict[str, dict[str, Any]]
    body: BodySpec
    controller: ControllerSpec
    reward: RewardSpec
    env: EnvSpec
    engine: EngineSpec
    urdf: Path
    layout: BodyLayout
    data_root: Path
    # The group files chosen by name (a body class's default body included): what the body's default
    # controller is composed from (thesis_controller)
    defaults: dict[str, str] = field(default_factory=dict)
    score_rewards: dict[str, RewardSpec] = field(default_factory=dict)

    # -- assembling -------------------------------------------------------------------------------------
    @classmethod
    def from_groups(cls, motion: str | os.PathLike | Motion, body=None, controller=None, reward=None, env=None,
                    engine=None, data_root: str | os.PathLike | None = None, complete: bool = False,
                    defaults: Mapping[str, str] | None = None,
                    score_rewards: Mapping[str, str | dict] | None = None) -> "ImitationSetup":
        """Each group a name, a (partial) dict or None. Names (and ``defaults``, group -> file name,
        for the groups given as None or a partial dict) are composed as ``aslexp imitate GROUP=NAME``
        composes them: a body named brings its own controller, reward and env."""
        given = {"body": body, "controller": controller, "reward": reward, "env": env, "engine": engine}
        chosen = {**(defaults or {}), **{name: value for name, value in given.items() if isinstance(value, str)}}
        for name, value in chosen.items():
            check_choice(name, value)  # a name that is no file: one line naming the group and what there is
        # composed only when a group is named or merged over its file (a job's complete groups need none)
        needed = any(value is None or isinstance(value, str) or (isinstance(value, dict) and not complete
                                                                  and name != "engine")
                      for name, value in given.items())
        composed = compose(IMITATE, [f"{name}={value}" for name, value in chosen.items()]) if needed else {}
        groups = {}
        for name, value in given.items():
            if isinstance(value, dict) and (complete or name == "engine"):
                groups[name] = dict(value)
            elif isinstance(value, dict):
                groups[name] = deep_merge(composed[name], value)
            else:
                groups[name] = composed[name]
        if data_root is None:
            from aslexp.data.root import resolve_data_root

            data_root = resolve_data_root(None, must_exist=False)
        scores = {str(name): RewardSpec.parse(value if isinstance(value, dict) else resolve_group("reward", value))
                  for name, value in (score_rewards or {}).items()}
        return cls._parse(motion, groups, Path(data_root), chosen, scores)

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any], data_root: str | os.PathLike | None = None,
                    score_rewards: Mapping[str, str | dict] | None = None) -> "ImitationSetup":
        """A job's composed config (its ``motion.file`` and every group complete)."""
        return cls.from_groups(cfg["motion"]["file"], cfg["body"], cfg["controller"], cfg["reward"], cfg["env"],
                               cfg.get("engine"), data_root=data_root, complete=True, score_rewards=score_rewards)

    @classmethod
    def _parse(cls, motion, groups: dict[str, dict], data_root: Path, defaults: dict[str, str],
               score_rewards: dict[str, RewardSpec]) -> "ImitationSetup":
        body = BodySpec.parse(groups["body"])
        urdf, layout = load_layout(body, data_root)
        return cls(motion=_load_motion(motion, layout, data_root), groups=groups, body=body,
                   controller=ControllerSpec.parse(groups["controller"]),
                   reward=RewardSpec.parse(groups["reward"]), env=EnvSpec.parse(groups["env"]),
                   engine=EngineSpec.parse(groups["engine"]), urdf=urdf, layout=layout, data_root=data_root,
                   defaults=dict(defaults), score_rewards=dict(score_rewards))

    def merged(self, **overrides: Mapping[str, Any] | str) -> "ImitationSetup":
        """This experiment with some groups changed: a dict is merged over this setup's group (a
        baseline row's ``body: {base: pinned}``), a name replaces it with that file."""
        groups = dict(self.groups)
        for name, value in overrides.items():
            if name not in GROUPS:
                raise ValueError(f"unknown config group {name!r}; expected one of {GROUPS}")
            groups[name] = resolve_group(name, value) if isinstance(value, str) else deep_merge(groups[name], dict(value))
        body_changed = groups["body"] != self.groups["body"]
        if not body_changed:  # the same body: the parsed motion and layout stay
            return replace(self, groups=groups, controller=ControllerSpec.parse(groups["controller"]),
                           reward=RewardSpec.parse(groups["reward"]), env=type(self.env).parse(groups["env"]),
                           engine=EngineSpec.parse(groups["engine"]))
        return self._parse(self.motion, groups, self.data_root, self.defaults, self.score_rewards)

    def load_motion(self, motion: str | os.PathLike | Motion) -> Motion:
        """Another motion for this body (a name in ``conf/motion``, a file, or a :class:`Motion`),
        checked against its layout: a pool's motions, a motion to perform."""
        return _load_motion(motion, self.layout, self.data_root)

    # -- what the consumers build ---------------------------------------------------------------------------
    @cached_property
    def reference(self) -> ReferenceMotion:
        """The motion read through the body's layout (its velocity tables built once per setup)."""
        return ReferenceMotion(self.motion, self.layout)

    def physics(self) -> PhysicsConfig:
        return PhysicsConfig(self.env.physics_hz, self.env.gravity, self.env.solver_iterations,
                             self.env.non_contact_inner_iterations)

    def simulation(self, render: bool = False) -> Simulation:
        """The engine's simulated and reference characters, at the reference's first root pose."""
        root_pos, root_rot, _, _ = self.reference.root(0.0)
        return build_simulation(self.engine, SimulationRequest(self.urdf, self.body, self.layout, self.physics(),
                                                               root_pos, root_rot, render=render))

    def pd_controller(self, spec: ControllerSpec | None = None) -> PDController:
        return PDController(spec or self.controller, self.layout)

    def thesis_controller(self) -> ControllerSpec:
        """The body's default controller (the thesis' gains): the baselines' bar. The body is the
        one chosen by name, else the body file named like this setup's body (a job's composed body)."""
        body = self.defaults.get("body") or self.body.name
        overrides = [f"body={body}"] if body and (CONF_DIR / "body" / f"{body}.yaml").is_file() else []
        return ControllerSpec.parse(group("controller", None, overrides=overrides))

    def reward_function(self, spec: RewardSpec | None = None) -> ImitationReward:
        return ImitationReward(spec or self.reward, self.layout)


def resolve_motion_path(motion: str | os.PathLike, data_root: str | os.PathLike | None) -> Path:
    """A motion file given absolutely, relative to the current directory, or to the data root; or
    a motion's name in ``conf/motion`` (``"A"``, ``"00433"``)."""
    path = Path(motion).expanduser()
    if path.is_absolute() or path.is_file():
        return path
    if _is_motion_name(path):
        path = Path(group("motion", str(path))["file"])
    return _data_root(data_root) / path


def find_motion_file(motion: str | os.PathLike, data_root: str | os.PathLike | None) -> Path:
    """:func:`resolve_motion_path`, or a FileNotFoundError whose one line names every place looked at."""
    path = resolve_motion_path(motion, data_root)
    if path.is_file():
        return path
    given = Path(motion).expanduser()
    if given.is_absolute():
        raise FileNotFoundError(f"motion file {motion} not found (an absolute path: looked nowhere else)")
    named = f" (conf/motion/{given}.yaml names file {group('motion', str(given))['file']})" \
        if _is_motion_name(given) else ""
    raise FileNotFoundError(
        f"motion file {motion}{named} not found; looked at {Path.cwd() / given} (as given, relative to the "
        f"current directory {Path.cwd()}) and at {path} (under the data root {_data_root(data_root)}; "
        f"data_root= or $ASLEXP_DATA_ROOT sets it)")


def _is_motion_name(path: Path) -> bool:
    return not path.suffix and len(path.parts) == 1 and (CONF_DIR / "motion" / f"{path}.yaml").is_file()


def _data_root(data_root: str | os.PathLike | None) -> Path:
    if data_root is None:
        from aslexp.data.root import resolve_data_root

        data_root = resolve_data_root(None, must_exist=False)
    return Path(data_root)


def _load_motion(motion: str | os.PathLike | Motion, layout: BodyLayout, data_root: Path) -> Motion:
    if isinstance(motion, Motion):
        if motion.num_columns != layout.motion_columns:
            raise ValueError(f"{motion.source or 'motion'}: the model expects {layout.motion_columns} values "
                             f"per frame but the motion has {motion.num_columns}")
        return motion
    try:
        return load_motion(find_motion_file(motion, data_root), expected_columns=layout.motion_columns,
                           quaternions=layout.quaternion_columns)
    except MotionFormatError as err:
        raise MotionFormatError(f"{err}{_bodies_for(err.found, data_root)}") from None


def _bodies_for(found: int | None, data_root: str | os.PathLike | None) -> str:
    """A hint naming the bodies (``conf/body``) whose motions have ``found`` values per frame."""
    if found is None:
        return ""
    fits = []
    for path in sorted((CONF_DIR / "body").glob("*.yaml")):
        try:
            _, layout = load_layout(BodySpec.parse(resolve_group("body", path.stem)), data_root)
        except Exception:  # noqa: BLE001 - a hint only: a body that cannot load fits nothing
            continue
        if layout.motion_columns == found:
            fits.append(f"body={path.stem}")
    return f"; {' or '.join(fits)} runs motions of that width" if fits else ""


ROOT_TRAVEL_WARNING_M = 0.25  # the thesis' clips hold their root still (0.0 m)
_warned_travel: set[str] = set()


def warn_travelling_root(motion: Motion, base: str) -> None:
    """Warn (once per file) when a clip's root travels but the body's root is held still: the
    pose is then tracked from the wrong place and the reward stays near zero (a walk on a fixed
    root scores ~0.04)."""
    if base == "free" or motion.num_frames < 2 or (motion.source or "") in _warned_travel:
        return
    root = np.asarray(motion.frames)[:, :3]
    travel = float(np.linalg.norm(root - root[0], axis=1).max())
    if travel > ROOT_TRAVEL_WARNING_M:
        _warned_travel.add(motion.source or "")
        log.warning("%s: the root travels %.2f m over the clip, but body.base=%s holds it at its first pose: "
                    "the pose is tracked from the wrong place and the reward will be low; a free root "
                    "follows it (body.base=free)", motion.source or "motion", travel, base)
