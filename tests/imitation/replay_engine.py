"""A test-only engine registered from the tests, with no edit to aslexp: it replays the PD targets.

Kinematics only: the body is wherever the controller asks it to be, at the speed that takes it
there in one control step (a perfect tracker, whatever the gains). Its characters are PyBullet's
kinematic pose holders, reached through their public pose methods alone (forward kinematics is not
what this engine shows). ``conf/engine/replay.yaml`` for a job::

    name: replay
    module: replay_engine      # this file, importable (PYTHONPATH)
    lag: 0.0                   # this engine's own key: the fraction of the way it does not go
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aslexp.sim.engine import EngineSpec, Simulation, SimulationRequest, register_engine
from aslexp.sim.world import Character, World


@dataclass(frozen=True)
class ReplayOptions:
    lag: float = 0.0  # 0: the targets exactly; 0.5: half way


class ReplayCharacter:
    """An :class:`aslexp.sim.engine.EngineCharacter` that moves to its targets."""

    def __init__(self, request: SimulationRequest, options: ReplayOptions) -> None:
        self.pose = Character(World(request.physics), request.urdf, request.body, request.layout,
                              request.root_position, request.root_rotation, kinematic=True)
        self.options, self.dt = options, 1.0 / request.physics.physics_hz
        self.link_names, self.num_links = self.pose.link_names, self.pose.num_links
        self.end_effector_links, self.base = self.pose.end_effector_links, request.body.base
        self.world = None  # no world anyone may step
        self.drives = 0

    def set_state(self, q, qd=None):
        self.q, self.qd = np.asarray(q, float).copy(), (np.zeros(0) if qd is None else np.asarray(qd, float).copy())
        self.pose.set_state(q, qd)

    def set_base(self, position, orientation_wxyz, linear_velocity=(0.0, 0.0, 0.0), angular_velocity=(0.0, 0.0, 0.0)):
        self.pose.set_base(position, orientation_wxyz)

    def joint_state(self):
        return self.pose.joint_state()[0], self.qd.copy()

    def base_state(self):
        return self.pose.base_state()

    def link_states(self, velocities=True, links=None):
        return self.pose.link_states(velocities=False, links=links)

    def end_effector_positions(self, links=None):
        return self.pose.end_effector_positions(links)

    def ground_contacts(self, ground):
        return set()

    def check_controller(self, controller):
        pass

    def drive(self, controller, targets, target_velocities, substeps):
        self.drives += 1
        q = self.q + (1.0 - self.options.lag) * (np.asarray(targets, float) - self.q)
        qd = (q - self.q) / (substeps * self.dt)
        self.set_state(q, qd)


@register_engine("replay", options=ReplayOptions, summary="test only: replays the PD targets")
def build(spec: EngineSpec, request: SimulationRequest) -> Simulation:
    sim = ReplayCharacter(request, spec.options)
    ref = Character(World(request.physics), request.urdf, request.body, request.layout, request.root_position,
                    request.root_rotation, kinematic=True)

    def close():
        sim.pose.world.close()
        ref.world.close()

    return Simulation(sim=sim, ref=ref, ground=None, close_fn=close)
