"""aslexp: an experiment platform for sign-language research.

Two wings over one foundation: phonological property recognition (WLASL x ASL-LEX)
and imitation (simulated hands and an upper-body humanoid learning signs with PPO).
"""

__version__ = "0.4.0"
from aslexp import envs as _envs  # noqa: E402,F401  (registers the gymnasium environments)
