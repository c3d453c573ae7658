"""Simulation layer of the imitation wing: URDF models, motions, PyBullet worlds, PD control.

Plain Python (no Hydra, no gymnasium): ``urdf`` (hand builder, joint tables), ``motion``
(DeepMimic motion files), ``body`` (joint groups, motion layout), ``world`` (PyBullet in DIRECT
mode, characters), ``pd`` (gains per joint group), ``reference`` (a motion read through a body).
"""
