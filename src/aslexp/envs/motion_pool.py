"""The motions one policy trains on (one policy, many motions): ``conf/train_motions/*.yaml``.

A pool is motions named as ``motion=`` names them (``conf/motion`` names or files) and ``generated.count``
smooth random ones like them (:func:`aslexp.sim.motion.generated_motions`: their durations, frame steps
and joint speeds, inside the body's joint limits). With ``hold_out_evaluated`` (the default) the run's
own motion, the one its evaluations and baselines score, is taken out of both lists: the policy never
trains on it, nor on motions made to its measure, so the run's headline is a zero-shot score.

``folder``: real signs too, every plausible motion of an ``aslexp extract --motions`` folder whose gloss
is outside the fold's test glosses (K ``folds`` by gloss, :mod:`aslexp.envs.sign_folds`), the thesis'
signs with them (``include_thesis_signs``). ``validation_motions``: that many motions of the next fold's
glosses (``validation_from: thesis_signs``: of the thesis' other signs; out of the pool too) score the
policy during training, to choose the checkpoint the run keeps (``MotionPool.validation``; the
trainer's ``validate``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aslexp.config_schema import Choice, Int, Section, key
from aslexp.envs.assembly import ImitationSetup, resolve_motion_path
from aslexp.envs.sign_folds import fold_pool, read_sign_folder, with_thesis_signs
from aslexp.errors import ConfigError
from aslexp.paths import CONF_DIR
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
    # real signs folded by gloss (aslexp.envs.sign_folds); None: no folder
    folder: str | None = None  # relative to the current directory, else to the data root
    folds: int = field(default=5, metadata=key(Int(2)))
    fold: int | None = None  # None: the fold whose test glosses hold the run's motion's gloss
    seed: int = field(default=0, metadata=key(Int(0)))
    include_thesis_signs: bool = False
    validation_motions: int = field(default=0, metadata=key(Int(0)))  # 0: no validation (the folder's only)
    # whose motions validate: the next fold's glosses, or the thesis' signs outside the test glosses
    validation_from: str = field(default="next_fold", metadata=key(Choice("next_fold", "thesis_signs")))
    thesis_signs: dict[str, str] = field(default_factory=dict)  # conf/motion name -> its WLASL gloss


@dataclass(frozen=True)
class MotionPool:
    """The training motions and what a run folder records of them."""

    motions: list[Motion]
    listed: list[str]  # the named motions trained on
    held_out: str | None  # the evaluated motion, taken out
    generated: int
    signs: dict | None = None  # the folder's fold (SignFold.summary); None: no folder
    validation: dict[str, Motion] = field(default_factory=dict)  # name -> motion: scored, never trained

    def summary(self) -> dict:
        return {"listed": self.listed, "generated": self.generated, "held_out": self.held_out,
                "count": len(self.motions), **({"signs": self.signs} if self.signs is not None else {})}


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
    signs = sign_fold(spec, root, evaluated) if spec.folder is not None else None
    if not listed and not gen.count and signs is None:
        raise ConfigError(f"train_motions {spec.name}: no motion left to train on (listed {list(spec.motions)}, "
                          f"held out {held}, generated.count 0)")
    if gen.count and not like:
        raise ConfigError(f"train_motions.generated.like: no motion left to make generated motions like "
                          f"(held out {held})")
    if spec.validation_motions and spec.folder is None:
        raise ConfigError(f"train_motions.validation_motions={spec.validation_motions}: validation motions are "
                          f"a folder's (train_motions.folder); this pool has none")
    motions = [setup.load_motion(m) for m in listed]
    validation = {}
    if signs is not None:
        motions += [setup.load_motion(c.file) for c in signs.train]
        validation = {c.name: setup.load_motion(c.file) for c in signs.validation}
    if gen.count:
        joints = setup.layout.joints
        made = generated_motions([setup.load_motion(m) for m in like], [j.lower for j in joints],
                                 [j.upper for j in joints], gen.count, seed=gen.seed, keyframes=gen.keyframes,
                                 close_loop=gen.close_loop)
        motions += made
    held_out = Path(str(evaluated)).stem if held or (signs is not None and signs.held_out) else None
    return MotionPool(motions, listed, held_out, gen.count, signs.summary() if signs is not None else None,
                      validation)


def sign_fold(spec: TrainMotionsSpec, data_root: Path, evaluated: str | None = None):
    """``spec.folder``'s fold (:func:`aslexp.envs.sign_folds.fold_pool`), the thesis' signs in it
    with ``include_thesis_signs``; ``evaluated``: the run's motion (held out with its gloss)."""
    folder = Path(spec.folder).expanduser()
    if not folder.is_absolute() and not folder.is_dir():
        folder = Path(data_root) / folder
    if not folder.is_dir():
        raise ConfigError(f"train_motions.folder={spec.folder}: no such folder (here or in the data root "
                          f"{data_root}); expected the --out folder of `aslexp extract --motions`")
    clips = read_sign_folder(folder)
    thesis = {name: (gloss, thesis_sign_file(name, data_root)) for name, gloss in spec.thesis_signs.items()}
    if spec.include_thesis_signs:
        clips = with_thesis_signs(clips, thesis)
    own = None if evaluated is None else resolve_motion_path(evaluated, data_root)
    return fold_pool(clips, spec.folds, spec.fold, spec.seed, str(spec.folder), own, spec.validation_motions,
                     spec.validation_from)


def thesis_sign_file(name: str, data_root: Path) -> Path:
    """``conf/motion/<name>.yaml``'s motion file, read as data (a name such as 52861 is no Hydra override:
    it would be read as a number)."""
    import yaml

    conf = CONF_DIR / "motion" / f"{name}.yaml"
    if not conf.is_file():
        raise ConfigError(f"train_motions.thesis_signs.{name}: no {conf}; expected a motion name of conf/motion")
    return resolve_motion_path((yaml.safe_load(conf.read_text()) or {}).get("file", ""), data_root)


def describe(pool: MotionPool) -> str:
    """One line for the log."""
    speeds = [mean_joint_speed(m) for m in pool.motions]
    signs = "" if pool.signs is None else (
        f" + {len(pool.signs['motions'])} signs of {len(pool.signs['glosses'])} glosses (fold {pool.signs['fold']} of "
        f"{pool.signs['folds']}, test glosses {', '.join(pool.signs['test_glosses'])}; "
        f"{pool.signs['implausible_left_out']['count']} implausible left out"
        + (f"; validated on {len(pool.validation)} motions of {', '.join(pool.signs['validation_glosses'])}"
           if pool.validation else "") + ")")
    return (f"{len(pool.motions)} training motions ({', '.join(pool.listed) or 'none listed'} + {pool.generated} "
            f"generated{signs}; held out: {pool.held_out or 'none'}), mean joint speed {np.mean(speeds):.2f} rad/s")
