"""One policy for several signs: an imitation environment over a set of clips (beyond the thesis'
one network per sign).

Each episode imitates one clip, drawn uniformly at reset (or named: ``options={"clip": k}``; the
evaluation env cycles through the clips). The observation is the clip's observation followed by
a one-hot clip code, so one policy conditions on which sign to make. All clips must share the
body (same observation and action spaces); each clip keeps its own
:class:`~aslexp.envs.imitation.ImitationEnv` (its own simulation and reference each).
"""

from __future__ import annotations

import os
from collections import defaultdict
from typing import Any

import gymnasium as gym
import numpy as np

from aslexp.envs.imitation import ImitationEnv
from aslexp.envs.upper_body import UpperBodyImitationEnv


class MultiClipImitationEnv(gym.Env):
    """Imitation of one of several motions per episode, with a one-hot clip code in the observation."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, motions: list[str | os.PathLike], cycle: bool = False,
                 env_class: type[ImitationEnv] = UpperBodyImitationEnv, **kwargs: Any) -> None:
        super().__init__()
        if not motions:
            raise ValueError("multi-clip env: give at least one motion")
        self.clips = [env_class(motion, **kwargs) for motion in motions]
        first = self.clips[0]
        for clip in self.clips[1:]:
            if clip.observation_space.shape != first.observation_space.shape or \
                    clip.action_space.shape != first.action_space.shape:
                raise ValueError(f"multi-clip env: {clip.motion.source} has spaces {clip.observation_space.shape}/"
                                 f"{clip.action_space.shape}, {first.motion.source} has "
                                 f"{first.observation_space.shape}/{first.action_space.shape}; one body for all clips")
        self.names = [os.path.splitext(os.path.basename(str(c.motion.source)))[0] for c in self.clips]
        self.cycle = cycle
        self.forced_clip: int | None = None  # aslexp.rl.evaluate.evaluate_clips: every reset takes this clip
        self.active = 0
        self._next = 0
        n = len(self.clips)
        low = np.concatenate([first.observation_space.low, np.zeros(n, np.float32)])
        high = np.concatenate([first.observation_space.high, np.ones(n, np.float32)])
        self.observation_space = gym.spaces.Box(low, high, dtype=np.float32)
        self.action_space = first.action_space
        self.render_mode = first.render_mode

    @property
    def env(self) -> ImitationEnv:
        """The clip of the current episode."""
        return self.clips[self.active]

    def __getattr__(self, name: str) -> Any:
        # reference_action, spec_env, layout, sim, reference, time, ...: the current clip's.
        if name.startswith("__") or name in ("clips", "active", "forced_clip", "cycle", "names"):
            raise AttributeError(name)
        return getattr(self.clips[self.active], name)

    def _with_code(self, obs: np.ndarray) -> np.ndarray:
        code = np.zeros(len(self.clips), np.float32)
        code[self.active] = 1.0
        return np.concatenate([obs, code])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        options = dict(options or {})
        if "clip" in options:
            self.active = int(options.pop("clip"))
        elif self.forced_clip is not None:
            self.active = self.forced_clip
        elif self.cycle:
            self.active, self._next = self._next, (self._next + 1) % len(self.clips)
        else:
            self.active = int(self.np_random.integers(len(self.clips)))
        obs, info = self.env.reset(seed=None if seed is None else seed + self.active, options=options)
        return self._with_code(obs), {**info, "clip": self.names[self.active]}

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self._with_code(obs), reward, terminated, truncated, {**info, "clip": self.names[self.active]}

    @property
    def counters(self) -> dict[str, int]:
        total: dict[str, int] = defaultdict(int)
        for clip in self.clips:
            for key, value in clip.counters.items():
                total[key] += value
        return dict(total)

    def pop_term_means(self) -> dict[str, float]:
        """Mean reward and terms since the last call, over all clips (weighted by their steps)."""
        sums: dict[str, float] = defaultdict(float)
        steps = 0.0
        for clip in self.clips:
            n = clip._term_sums.get("steps", 0)
            means = clip.pop_term_means()
            steps += n
            for key, value in means.items():
                sums[key] += value * n
        return {k: v / steps for k, v in sums.items()} if steps else {}

    def render(self):
        return self.env.render()

    def close(self) -> None:
        for clip in self.clips:
            clip.close()

