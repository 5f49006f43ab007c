"""An arm in MuJoCo driven as ros_control drives a real one: position targets for the joints a sim moves, held by
the model's servos (physics.model), time advanced in MuJoCo's steps; the joints' positions, velocities and efforts
(what a real arm's joint_states says), and the loose objects' poses. arm_sim's `~physics mujoco` runs on it. No
rospy.

    arm = ArmPhysics(build_physics(load_model('ur5.urdf'), obstacles='world.yaml'), joints)
    arm.step(target, 0.01)                 # 10 ms of physics toward target (one per joint of joints)
    arm.positions, arm.velocities, arm.efforts, arm.object_poses()
    arm.grip(0.0, max_effort=20.0)         # the gripper's servos toward closed, with at most 20 N
    arm.gripper_state()                    # its position, velocity and effort
"""
from __future__ import annotations

import numpy as np

from robot_ai.physics.model import Physics, PhysicsError, free_velocity

GRIP_TOLERANCE = 0.02       # a gripper command is reached within this share of the joint's range from its target
STALL_SPEED = 0.01          # a gripper is still below this share of its joint's range per second ...
STALL_TIME = 0.2            # ... for this long (s of physics): stalled, held short of its target


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
        self._gripper = np.array([physics.actuated.index(n) for n in physics.gripper], dtype=int)
        self._gripper_range = np.array([self.model.actuator_ctrlrange[k] if self.model.actuator_ctrllimited[k]
                                        else (-np.inf, np.inf) for k in self._gripper]).reshape(-1, 2)
        span = float(np.diff(self._gripper_range[0])[0]) if len(self._gripper) else 1.0
        self._span = span if np.isfinite(span) else 1.0      # the first joint's range: tolerances are shares of it
        self._force = self.model.actuator_forcerange.copy()    # the URDF's effort limits, max_effort's default
        self._grip: dict[int, tuple[float, float]] = {}    # actuator -> the gripper command's target and speed
        self._ramp: dict[int, float] = {}     # actuator -> where its target stands on the way to the command
        self._still = 0.0                     # s of physics the gripper has been still (for gripper_outcome)
        # object -> (its body, its free joint's qpos and qvel addresses)
        self._objects = {name: physics.object_addresses(name) for name in physics.objects}

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
            for k, (value, speed) in self._grip.items():   # the gripper's targets at most at its velocity limit
                reach = speed * self.model.opt.timestep
                self.data.ctrl[k] = self._ramp[k] = float(np.clip(value, self._ramp[k] - reach, self._ramp[k] + reach))
            self._mj.mj_step(self.model, self.data)
        self._mj.mj_kinematics(self.model, self.data)    # the bodies' poses of the joints' last positions
        self.time += steps * self.model.opt.timestep
        if self._grip:
            still = abs(self.gripper_state()[1]) < STALL_SPEED * self._span
            self._still = self._still + steps * self.model.opt.timestep if still else 0.0
        return steps

    def set_state(self, positions) -> None:
        """The joints at positions at once, at rest, their servos holding there (mimic joints placed by their
        source); the objects stay where they are."""
        positions = np.asarray(positions, dtype=float)
        if positions.shape != (len(self.joints),) or not np.isfinite(positions).all():
            raise PhysicsError(f'a state is {len(self.joints)} finite positions, got {positions.tolist()}')
        self.data.qpos[self._qpos] = positions
        self.data.ctrl[self._actuator] = positions
        for k in self._actuator:              # placed: a gripper joint placed here is the gripper command no more
            self._grip.pop(int(k), None)
        self.physics.follow_mimics(self.data)
        self.data.qvel[:] = 0.0
        self.data.qacc_warmstart[:] = 0.0
        self._mj.mj_forward(self.model, self.data)

    @property
    def gripper(self) -> tuple[str, ...]:
        """The gripper's actuated joints (physics.gripper); () for an arm without one."""
        return self.physics.gripper

    def grip(self, position: float, max_effort: float = 0.0) -> float:
        """The gripper command of ros_control's gripper_action_controller: the first actuated gripper joint's servo
        toward position (m or rad, clipped to its range), every other's toward the same share of its own range (a
        Kinova JACO2's fingertips close to 2 rad as its fingers to 1.51), with at most max_effort (N or N m; 0 or
        less: the URDF's effort limit), the targets moving there at the joints' velocity limits over the following
        steps and held, whatever those steps' targets give these joints, until set_state places them; the target
        taken (the first joint's). PhysicsError for an arm without a gripper or a position or effort that is not a
        number."""
        if not self.gripper:
            raise PhysicsError('the arm has no gripper (no actuated finger joints)')
        if not (np.isfinite(position) and np.isfinite(max_effort)):
            raise PhysicsError(f'a gripper command is a finite position and effort, got {position!r}, {max_effort!r}')
        low, high = self._gripper_range[:, 0], self._gripper_range[:, 1]
        targets = np.clip(float(position), low, high)
        if np.isfinite(self._gripper_range).all() and high[0] > low[0]:
            share = (targets[0] - low[0]) / (high[0] - low[0])
            targets = np.where((low == low[0]) & (high == high[0]), targets[0], low + share * (high - low))
        for k, value, speed in zip(self._gripper, targets, self.physics.gripper_speed):
            if int(k) not in self._grip:
                self._ramp[int(k)] = float(self.data.ctrl[k])
            self._grip[int(k)] = (float(value), speed)
            limit = self._force[k, 1] if self._force[k, 1] > 0 else np.inf
            effort = min(float(max_effort), limit) if max_effort > 0 else limit
            self.model.actuator_forcelimited[k] = np.isfinite(effort)
            self.model.actuator_forcerange[k] = (-effort, effort) if np.isfinite(effort) else (0.0, 0.0)
        self._still = 0.0
        return float(targets[0])

    def gripper_state(self) -> tuple[float, float, float]:
        """(position, velocity, effort) of the gripper's first actuated joint, as gripper_action_controller reports
        its joint."""
        if not self.gripper:
            raise PhysicsError('the arm has no gripper (no actuated finger joints)')
        j = self.model.actuator_trnid[self._gripper[0], 0]
        dof = self.model.jnt_dofadr[j]
        return (float(self.data.qpos[self.model.jnt_qposadr[j]]), float(self.data.qvel[dof]),
                float(self.data.qfrc_actuator[dof]))

    def gripper_outcome(self) -> tuple[bool, bool] | None:
        """How the last gripper command ended, as gripper_action_controller says it: (reached_goal, stalled), or
        None while the gripper still moves toward it. Reached: its first joint within GRIP_TOLERANCE of the range
        from the target; stalled: still for STALL_TIME short of it (an object held between the fingers)."""
        k = int(self._gripper[0]) if self.gripper else -1
        if k not in self._grip:
            return None
        tolerance = GRIP_TOLERANCE * self._span
        if abs(self.gripper_state()[0] - self._grip[k][0]) <= tolerance and self._ramp[k] == self._grip[k][0]:
            return True, False
        return (False, True) if self._still >= STALL_TIME and self._ramp[k] == self._grip[k][0] else None

    def object_poses(self) -> dict[str, np.ndarray]:
        """{object: 4x4 pose in the world (the root's frame)}."""
        return {name: self.physics.object_pose(self.data, name) for name in self.physics.objects}

    def object_states(self) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """{object: (position (3), orientation (4: w, x, y, z, MuJoCo's), velocity (6: linear, angular))}, all in
        the world (the root's frame), as the manipulation envs observe them."""
        out = {}
        for name, (body, _, dof) in self._objects.items():
            out[name] = (self.data.xpos[body].copy(), self.data.xquat[body].copy(),
                         free_velocity(self.data, body, dof))
        return out

    def set_object(self, name: str, position, orientation) -> None:
        """The object name at position (3) with orientation (4: w, x, y, z; normalised), at rest, in the world (the
        root's frame); the arm stays as it is. PhysicsError of one line for an unknown object or a pose that is not
        one."""
        if name not in self._objects:
            raise PhysicsError(f'no object {name!r} (the objects: {", ".join(self._objects) or "none"})')
        p, q = np.asarray(position, dtype=float), np.asarray(orientation, dtype=float)
        norm = float(np.linalg.norm(q)) if q.shape == (4,) else 0.0
        if p.shape != (3,) or not np.isfinite(p).all() or not (np.isfinite(q).all() and abs(norm - 1.0) < 1e-3):
            raise PhysicsError(f'a pose is a finite position and a unit quaternion, got {p.tolist()}, {q.tolist()}')
        _, address, dof = self._objects[name]
        self.data.qpos[address:address + 7] = [*p, *(q / norm)]
        self.data.qvel[dof:dof + 6] = 0.0
        self.data.qacc_warmstart[:] = 0.0
        self._mj.mj_forward(self.model, self.data)
