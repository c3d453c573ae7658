"""PyBullet's C-side chatter stays out of logs (the thesis URDF warns once per spherical joint, in
every worker), and a real failure keeps its C-side message."""

from __future__ import annotations

import pytest

from aslexp.envs.upper_body import UpperBodyImitationEnv
from aslexp.sim._pybullet import c_output_quieted
from aslexp.sim.world import World


def test_loading_the_thesis_urdf_prints_nothing(capfd, data_root):
    env = UpperBodyImitationEnv("motions/upper_body/00433.txt", data_root=data_root)
    env.close()
    out, err = capfd.readouterr()
    assert "b3Warning" not in out + err and "no axis element" not in out + err


def test_a_failed_load_writes_the_c_message_back(capfd):
    world = World()
    with pytest.raises(Exception, match="Cannot load URDF"):
        with c_output_quieted((1, 2)):
            world.client.loadURDF("/nonexistent/body.urdf")
    out, err = capfd.readouterr()
    assert "/nonexistent/body.urdf' not found" in err
