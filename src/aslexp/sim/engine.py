"""The engine seam: what a physics engine gives the imitation wing, and the registry that finds one.

An engine simulates one body config (``conf/body``) from its URDF and answers in motion-layout
terms. Everything above it (the reference, observation, action, reward, PD gains, the PPO loop,
the reports) talks to the objects declared here and never names an engine. Two are built in:
PyBullet (:mod:`aslexp.sim.world`, the thesis' engine and the default) and MuJoCo
(:mod:`aslexp.sim.mujoco_engine`, many environments per process: :mod:`aslexp.envs.batched`).

A new engine is a registration, not a patch (as a keypoint format is, :mod:`aslexp.keypoints.registry`)::

    from aslexp.sim.engine import register_engine

    @register_engine("kinematic", summary="replays the PD targets: a perfect tracker")
    def build(spec, request):          # an EngineSpec, a SimulationRequest
        return Simulation(sim=..., ref=..., ground=None)

plus ``conf/engine/kinematic.yaml`` (``name: kinematic`` and ``module: my_package.my_engine``,
the module imported to register it, or an entry point of the group ``aslexp.engines``).
An engine's own keys (MuJoCo's integrator, solver, ...) are a frozen dataclass given as
``options=``: a YAML key it does not declare is refused with the engine's name.

The character protocol (:class:`EngineCharacter`) is what the single environment reads and writes;
an engine that steps many environments at once also gives :attr:`Simulation.batch`, an object with
the :class:`BatchedBody` methods, which :class:`~aslexp.envs.batched.BatchedImitationEnv` drives.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from aslexp.config_schema import Section, Text, key, read, shown
from aslexp.errors import ConfigError
from aslexp.plugins import import_registering_module, load_entry_points


ENTRY_POINT_GROUP = "aslexp.engines"
# The built-in engines' modules, imported the first time their name is asked for: importing this
# module loads neither PyBullet nor MuJoCo.
BUILT_IN = {"pybullet": "aslexp.sim.world", "mujoco": "aslexp.sim.mujoco_engine"}


@dataclass(frozen=True)
class PhysicsConfig:
    """Physics settings every engine reads (``conf/env/*.yaml`` holds them next to the control rate)."""

    physics_hz: float = 240.0
    gravity: tuple[float, float, float] = (0.0, -9.8, 0.0)
    solver_iterations: int = 10
    # PyBullet's numNonContactInnerIterations: sweeps over the joint motors and limits inside each
    # solver iteration. For long articulated chains (the upper body) 10 x 10 converges where 100 x 1
    # does not (docs/imitation_upper_body.md, "Solver convergence").
    non_contact_inner_iterations: int = 1


# The rendering camera, looking at the mean link position: the hand's view (conf/env camera overrides it).
DEFAULT_CAMERA = {"distance": 0.5, "yaw": 90.0, "pitch": -10.0}


@dataclass(frozen=True)
class EngineReport(Section):
    """``report:`` of ``conf/engine/<name>.yaml``: what a results row says about the engine (its
    "Differences from the thesis" line, :mod:`aslexp.results.differences`, which names no engine).

    ``text`` is the sentence, its ``{field}`` filled from ``parts`` and from the engine section's own
    values (``{motor_gain_scale:g}``). A part is chosen by one value: ``by`` names it (an engine key,
    or ``controller.mode``), the part's entry for that value (``"null"`` for null) is used, else its
    ``otherwise`` (else nothing). Without ``report:`` (an engine of the tests) a row says the name."""

    SECTION = "engine.report"

    text: str = field(metadata=key(Text()))
    parts: dict[str, dict[str, str]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, part in self.parts.items():
            if "by" not in part:
                raise ConfigError(f"parts.{name}: expected a `by:` naming the value that chooses the text")


@dataclass(frozen=True)
class EngineSpec:
    """``conf/engine/<name>.yaml``: the engine's ``name``, the ``module`` that registers it (None:
    built in or an entry point), what a report says about it (``report``, :class:`EngineReport`;
    every engine may have one, nothing simulated reads it) and its own keys, parsed by its options
    class (``options``)."""

    name: str = "pybullet"
    module: str | None = None
    options: Any = None
    report: EngineReport | None = field(default=None, compare=False)

    def replace(self, **changes: Any) -> "EngineSpec":
        """This spec with some of the engine's own keys changed (e.g. ``threads``)."""
        return dataclasses.replace(self, options=dataclasses.replace(self.options, **changes))

    @classmethod
    def parse(cls, values: Mapping[str, Any] | None, section: str = "engine") -> "EngineSpec":
        """The engine's ``name`` and ``module``; its own keys are read into its options class by the
        one reader (:func:`aslexp.config_schema.read`)."""
        values = dict(values or {})
        name = values.pop("name", "pybullet")
        module = values.pop("module", None)
        report = values.pop("report", None)
        report = None if report is None else read(EngineReport, report, f"{section}.report")
        entry = get_engine(name, module)
        if entry.options is None:
            if values:
                first = next(iter(values))
                raise ConfigError(f"{section}.{first}={shown(values[first])}: unknown key; engine {name} takes "
                                  f"none besides name, module and report")
            return cls(name=name, module=module, options=None, report=report)
        return cls(name=name, module=module, options=read(entry.options, values, section), report=report)


@dataclass(frozen=True)
class SimulationRequest:
    """What an engine builds: a body (its URDF, config and layout) at the reference's first root
    pose, under the environment's physics settings; ``render``: images will be asked for."""

    urdf: Any
    body: Any  # aslexp.sim.body.BodySpec
    layout: Any  # aslexp.sim.body.BodyLayout
    physics: PhysicsConfig
    root_position: np.ndarray
    root_rotation: np.ndarray
    render: bool = False


@runtime_checkable
class EngineCharacter(Protocol):
    """One body in an engine, in motion-layout terms (joint vector q in motion order, a spherical
    joint's quaternion as w x y z, velocities 1 per revolute and 3 per spherical joint)."""

    link_names: list[str]
    num_links: int
    end_effector_links: list[int]
    base: str  # fixed | pinned | free

    def set_state(self, q: np.ndarray, qd: np.ndarray | None = None) -> None: ...
    def set_base(self, position, orientation_wxyz, linear_velocity=(0.0, 0.0, 0.0),
                 angular_velocity=(0.0, 0.0, 0.0)) -> None: ...
    def joint_state(self) -> tuple[np.ndarray, np.ndarray]: ...
    def base_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]: ...
    def link_states(self, velocities: bool = True, links: list[int] | None = None) -> np.ndarray: ...
    def end_effector_positions(self, links: np.ndarray | None = None) -> np.ndarray: ...
    def ground_contacts(self, ground: Any) -> set[int]: ...
    # PD control (aslexp.sim.pd.PDController holds the gains): hold the targets for `substeps`
    # physics steps, and refuse a controller this engine cannot run on this body.
    def drive(self, controller, targets: np.ndarray, target_velocities: np.ndarray | None,
              substeps: int) -> None: ...
    def check_controller(self, controller) -> None: ...


class BatchedBody(Protocol):
    """Many environments of one body as rows of a state array (an engine with ``batched=True``)."""

    link_names: list[str]
    peak_speeds: np.ndarray  # per row, the fastest joint of the last step before any speed clamp

    def set_gains(self, controller) -> None: ...
    def set_threads(self, threads: int) -> None: ...
    def new_states(self, n: int) -> np.ndarray: ...
    def write(self, states, rows, q, qd, root_pos, root_rot, root_vel, root_ang) -> None: ...
    def controls(self, targets: np.ndarray, target_velocities: np.ndarray | None = None) -> np.ndarray: ...
    def step(self, states: np.ndarray, ctrl: np.ndarray, nstep: int) -> np.ndarray: ...
    def joints(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...
    def read(self, states: np.ndarray, tips_only: bool = False) -> np.ndarray: ...
    def frames(self, sensors: np.ndarray) -> np.ndarray: ...
    def tips(self, sensors: np.ndarray) -> np.ndarray: ...
    def contacts(self, state: np.ndarray) -> set[int]: ...


@dataclass
class Simulation:
    """What an engine builds for one environment: the simulated character (stepped), a kinematic
    reference character (posed, never stepped), the ground (free bases; None otherwise) and, for
    engines that batch, the body every row of a batch shares."""

    sim: EngineCharacter
    ref: EngineCharacter
    ground: Any = None
    batch: BatchedBody | None = None
    render_fn: Callable[[dict[str, float], tuple[int, int]], np.ndarray] | None = None
    close_fn: Callable[[], None] | None = None

    def render(self, camera: dict[str, float], size: tuple[int, int]) -> np.ndarray:
        """The reference (left) and the simulation (right) side by side, (H, 2W, 3) uint8."""
        if self.render_fn is None:
            raise ConfigError("this engine draws no images (render_mode rgb_array needs an engine that renders)")
        return self.render_fn(camera, size)

    def close(self) -> None:
        if self.close_fn is not None:
            self.close_fn()
            self.close_fn = None


@dataclass(frozen=True)
class EngineEntry:
    """A registered engine: ``build(spec, request) -> Simulation``; ``options``: the dataclass of
    its own keys (None: it has none); ``batched``: its Simulation carries a :class:`BatchedBody`
    (the imitate job's ``vector_env: auto`` then steps every environment in one batch);
    ``divergence_hint``: what to change when a simulation blows up on it."""

    name: str
    build: Callable[[EngineSpec, SimulationRequest], Simulation]
    options: type | None = None
    batched: bool = False
    summary: str = ""
    divergence_hint: str = "a smaller physics step (env.physics_hz) or softer gains"


_ENGINES: dict[str, EngineEntry] = {}


def register_engine(name: str, *, options: type | None = None, batched: bool = False, summary: str = "",
                    divergence_hint: str | None = None, replace: bool = False):
    """Decorator: make ``build(spec, request) -> Simulation`` the engine ``name``."""

    def decorate(build: Callable[[EngineSpec, SimulationRequest], Simulation]):
        known = _ENGINES.get(name)
        if known is not None and known.build is not build and not replace:
            raise ConfigError(f"engine {name!r} is already registered ({known.build.__module__}); "
                              "choose another name or pass replace=True")
        extra = {} if divergence_hint is None else {"divergence_hint": divergence_hint}
        _ENGINES[name] = EngineEntry(name, build, options, batched, summary, **extra)
        return build

    return decorate


def unregister_engine(name: str) -> None:
    """Forget a registered engine (tests register throwaway ones)."""
    _ENGINES.pop(name, None)


def _load_entry_points() -> None:
    load_entry_points(ENTRY_POINT_GROUP, "engine")


def get_engine(name: str, module: str | None = None) -> EngineEntry:
    """The engine ``name``: registered already, built in, registered by importing ``module``
    (``conf/engine/<name>.yaml``'s ``module`` key) or by an installed entry point."""
    if name not in _ENGINES:
        target = module or BUILT_IN.get(name)
        if target:
            import_registering_module("engine", name, target)
        else:
            _load_entry_points()
    try:
        return _ENGINES[name]
    except KeyError:
        raise ConfigError(f"engine config: name must be one of {engine_names()}, got {name!r} "
                          f"(or give engine.module, the module that registers it)") from None


def engine_names() -> list[str]:
    _load_entry_points()
    return sorted(set(_ENGINES) | set(BUILT_IN))


def build_simulation(spec: EngineSpec, request: SimulationRequest) -> Simulation:
    """The engine of ``spec`` builds one environment's simulation."""
    return get_engine(spec.name, spec.module).build(spec, request)


def batching_engines() -> list[str]:
    """The engines whose simulations step many environments at once (``EngineEntry.batched``)."""
    for name in BUILT_IN:
        get_engine(name)
    _load_entry_points()
    return sorted(name for name, entry in _ENGINES.items() if entry.batched)
