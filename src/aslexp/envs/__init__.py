"""Gymnasium environments of the imitation wing, registered on ``import aslexp``.

Registration uses string entry points so that importing ``aslexp`` never imports a physics engine.
"""

from __future__ import annotations

HAND_IMITATION_ID = "aslexp/HandImitation-v0"
UPPER_BODY_IMITATION_ID = "aslexp/UpperBodyImitation-v0"


def register_envs() -> None:
    """Register the environments with gymnasium (idempotent; a no-op without gymnasium)."""
    try:
        from gymnasium.envs.registration import register, registry
    except ImportError:  # pragma: no cover - gymnasium is a dependency
        return
    if HAND_IMITATION_ID not in registry:
        register(
            id=HAND_IMITATION_ID,
            entry_point="aslexp.envs.imitation:ImitationEnv",
            kwargs={"body": "hand15"},
        )
    if UPPER_BODY_IMITATION_ID not in registry:
        register(id=UPPER_BODY_IMITATION_ID, entry_point="aslexp.envs.upper_body:UpperBodyImitationEnv")


register_envs()
