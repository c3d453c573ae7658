"""The upper-body humanoid with two hands imitating a whole sign (thesis chapter 6).

The same environment as the hand's (:class:`~aslexp.envs.imitation.ImitationEnv`), with the
upper body's config groups as defaults: ``body=upper_body`` (built model; ``upper_body_thesis``
loads the thesis' URDF), ``controller=upper_body`` (position control, fixed base),
``reward=upper_body_thesis`` (Eqs. 6.1-6.3, summed errors, Table 6.5 Run 4) and ``env=upper_body``
(30 Hz). The thesis' setting is ``controller=upper_body_thesis`` (the text's: body stable PD, hands
position control 0.22 / 0.87; the authors' code's all-stable-PD gains: ``upper_body_thesis_code``) with
``body.base=pinned`` (or ``free``) and ``env=upper_body_thesis`` (240 Hz). Registered as ``aslexp/UpperBodyImitation-v0``::

    gym.make("aslexp/UpperBodyImitation-v0", motion="motions/upper_body/00433.txt")
"""

from __future__ import annotations

from aslexp.envs.imitation import ImitationEnv

UPPER_BODY_DEFAULTS = {"body": "upper_body"}  # the body file brings its controller, reward and env


class UpperBodyImitationEnv(ImitationEnv):
    """:class:`ImitationEnv` whose config groups default to the upper body's files."""

    GROUP_DEFAULTS = UPPER_BODY_DEFAULTS
