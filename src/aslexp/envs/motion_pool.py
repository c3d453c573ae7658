"""The motions one policy trains on (issue 38: one policy, many motions): ``conf/train_motions/*.yaml``.

A pool is motions named as ``motion=`` names them (``conf/motion`` names or files) and ``generated.count``
smooth random ones like them (:func:`aslexp.sim.motion.generated_motions`: their durations, frame steps
and joint speeds, inside the body's joint limits). With ``hold_out_evaluated`` (the default) the run's
own motion, the one its evaluations and baselines score, is taken out of both lists: the policy never
trains on it, nor on motions made to its measure, so the run's headline is a zero-shot score.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aslexp.config_schema import Int, Section, key
from aslexp.envs.assembly import ImitationSetup, resolve_motion_path
from aslexp.errors import ConfigError
from aslexp.sim.motion import Motion, generated_motions, mean_joint_speed


@dataclass(frozen=True)
class GeneratedMotionsSpec(Section):
    """``train_motions.generated``: random motions made like the pool's listed ones."""

    SECTION = "train_motions.generated"

    count: int = field(default=0, metadata=key(Int(0)))
    seed: int = field(default=0, metadata=key(Int(0)))
    like: tuple[str, ...] | None = None  # None: the pool's listed motions (the held-out one taken out)
    keyframes: tuple[int, int] = (2, 4)  # poses per cycle, drawn between these two numbers
    close_loop: bool = False  # False: the jump back to the first pose at the wrap, as the letters have

    def __post_init__(self) -> None:
        low, high = self.keyframes
        if not 2 <= low <= high:
            raise ConfigError(f"keyframes={list(self.keyframes)}: expected [low, high] with 2 <= low <= high")


@dataclass(frozen=True)
class TrainMotionsSpec(Section):
    """``conf/train_motions/*.yaml`` as plain values (module docstring)."""

    SECTION = "train_motions"

    name: str = "train_motions"
    motions: tuple[str, ...] = ()
    hold_out_evaluated: bool = True
    generated: GeneratedMotionsSpec = field(default_factory=GeneratedMotionsSpec)


@dataclass(frozen=True)
class MotionPool:
    """The training motions and what a run folder records of them."""

    motions: list[Motion]
    listed: list[str]  # the named motions trained on
    held_out: str | None  # the evaluated motion, taken out
    generated: int

    def summary(self) -> dict:
        return {"listed": self.listed, "generated": self.generated, "held_out": self.held_out,
                "count": len(self.motions)}


def training_motions(spec: TrainMotionsSpec, setup: ImitationSetup, evaluated: str | None = None) -> MotionPool:
    """The pool of ``spec`` for ``setup``'s body; ``evaluated``: the run's motion (its name or file)."""
    root = setup.data_root

    def same(name: str) -> bool:
        if evaluated is None:
            return False
        return name == evaluated or resolve_motion_path(name, root).resolve() == \
            resolve_motion_path(evaluated, root).resolve()

    held = [m for m in spec.motions if same(m)] if spec.hold_out_evaluated else []
    listed = [m for m in spec.motions if m not in held]
    gen = spec.generated
    like = [m for m in (gen.like if gen.like is not None else spec.motions) if not (spec.hold_out_evaluated and same(m))]
    if not listed and not gen.count:
        raise ConfigError(f"train_motions {spec.name}: no motion left to train on (listed {list(spec.motions)}, "
                          f"held out {held}, generated.count 0)")
    if gen.count and not like:
        raise ConfigError(f"train_motions.generated.like: no motion left to make generated motions like "
                          f"(held out {held})")
    motions = [setup.load_motion(m) for m in listed]
    if gen.count:
        joints = setup.layout.joints
        made = generated_motions([setup.load_motion(m) for m in like], [j.lower for j in joints],
                                 [j.upper for j in joints], gen.count, seed=gen.seed, keyframes=gen.keyframes,
                                 close_loop=gen.close_loop)
        motions += made
    return MotionPool(motions, listed, Path(str(evaluated)).stem if held else None, gen.count)


def describe(pool: MotionPool) -> str:
    """One line for the log."""
    speeds = [mean_joint_speed(m) for m in pool.motions]
    return (f"{len(pool.motions)} training motions ({', '.join(pool.listed) or 'none listed'} + {pool.generated} "
            f"generated; held out: {pool.held_out or 'none'}), mean joint speed {np.mean(speeds):.2f} rad/s")
