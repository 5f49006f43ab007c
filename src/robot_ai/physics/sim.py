"""An arm in MuJoCo driven as ros_control drives a real one: position targets for the joints a sim moves, held by
the model's servos (physics.model), time advanced in MuJoCo's steps; the joints' positions, velocities and efforts
(what a real arm's joint_states says), and the loose objects' poses. arm_sim's `~physics mujoco` runs on it. No
rospy.

    arm = ArmPhysics(build_physics(load_model('ur5.urdf'), obstacles='world.yaml'), joints)
    arm.step(target, 0.01)                 # 10 ms of physics toward target (one per joint of joints)
    arm.positions, arm.velocities, arm.efforts, arm.object_poses()
"""
from __future__ import annotations

import numpy as np

from robot_ai.physics.model import Physics, PhysicsError


class ArmPhysics:
    """A Physics model's data, stepped toward position targets for joints (a subset of physics.actuated, in the
    caller's order); the actuated joints not named hold where they are."""

    def __init__(self, physics: Physics, joints):
        import mujoco
        self.physics, self.model = physics, physics.model
        self.joints = list(joints)
        missing = [n for n in self.joints if n not in physics.actuated]
        if missing:
            raise PhysicsError(f'{", ".join(missing)}: not joints the model\'s servos drive '
                               f'({", ".join(physics.actuated)})')
        self.data = physics.data()
        self._actuator = np.array([physics.actuated.index(n) for n in self.joints], dtype=int)
        ids = [mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in self.joints]
        self._qpos = self.model.jnt_qposadr[ids]
        self._dof = self.model.jnt_dofadr[ids]
        self._mj = mujoco
        self.time = 0.0

    @property
    def positions(self) -> np.ndarray:
        return self.data.qpos[self._qpos].copy()

    @property
    def velocities(self) -> np.ndarray:
        return self.data.qvel[self._dof].copy()

    @property
    def efforts(self) -> np.ndarray:
        """The joints' actuation (N m or N): the servo's and the weight it holds, as a real arm's effort reads."""
        return self.data.qfrc_actuator[self._dof].copy()

    @property
    def targets(self) -> np.ndarray:
        return self.data.ctrl[self._actuator].copy()

    def step(self, target, duration: float) -> int:
        """The servos of joints toward target (one position per joint) for duration seconds (whole MuJoCo steps, at
        least one); the number of steps taken."""
        target = np.asarray(target, dtype=float)
        if target.shape != (len(self.joints),) or not np.isfinite(target).all():
            raise PhysicsError(f'a target is {len(self.joints)} finite positions, got {target.tolist()}')
        self.data.ctrl[self._actuator] = target
        steps = max(1, int(round(duration / self.model.opt.timestep)))
        for _ in range(steps):
            self._mj.mj_step(self.model, self.data)
        self.time += steps * self.model.opt.timestep
        return steps

    def set_state(self, positions) -> None:
        """The joints at positions at once, at rest, their servos holding there (mimic joints placed by their
        source); the objects stay where they are."""
        positions = np.asarray(positions, dtype=float)
        if positions.shape != (len(self.joints),) or not np.isfinite(positions).all():
            raise PhysicsError(f'a state is {len(self.joints)} finite positions, got {positions.tolist()}')
        self.data.qpos[self._qpos] = positions
        self.data.ctrl[self._actuator] = positions
        for k in range(self.model.neq):       # a mimic joint: position = offset + multiplier x its source's
            if self.model.eq_type[k] == self._mj.mjtEq.mjEQ_JOINT:
                follower, source = self.model.eq_obj1id[k], self.model.eq_obj2id[k]
                offset, multiplier = self.model.eq_data[k, :2]
                self.data.qpos[self.model.jnt_qposadr[follower]] = \
                    offset + multiplier * self.data.qpos[self.model.jnt_qposadr[source]]
        self.data.qvel[:] = 0.0
        self.data.qacc_warmstart[:] = 0.0
        self._mj.mj_forward(self.model, self.data)

    def object_poses(self) -> dict[str, np.ndarray]:
        """{object: 4x4 pose in the world (the root's frame)}."""
        return {name: self.physics.object_pose(self.data, name) for name in self.physics.objects}
