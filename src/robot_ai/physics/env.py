"""Push-v0 and PickAndPlace-v0: any arm with a gripper pushes a cube, or picks it and places it, in MuJoCo (the model
of physics.model, laid out by physics.workspace). No rospy.

    env = gymnasium.make('robot_ai/Push-v0', model='/path/panda.urdf')          # 50 steps
    env = gymnasium.make('robot_ai/PickAndPlace-v0', model='/path/arm_with_gripper.urdf.xacro', tip='tool0')
    envs = gymnasium.make_vec('robot_ai/Push-v0', num_envs=64, model=...)   # ManipulationVectorEnv: the worlds at once

gymnasium-robotics' conventions (FetchPush, FetchPickAndPlace; panda-gym's PandaPush and PandaPickAndPlace are the
same): a goal env, ``Dict(achieved_goal=Box(3), desired_goal=Box(3), observation=Box(23))`` in float64, positions in
metres in the robot's root frame; achieved_goal is the cube's position; ``compute_reward(achieved_goal,
desired_goal, info)`` is vectorised over any leading dimensions (HER relabels on it); ``info['is_success']`` is the
cube within ``distance_threshold`` (0.05 m) of the goal. reward_type 'sparse': -1 outside, 0 inside; 'dense':
-distance. 50 steps (TimeLimit), no termination.

observation: the grip point (3), the cube's position (3), the cube relative to the grip point (3), the gripper's
opening (1: its first joint, 0 closed to 1 open), the cube's orientation (3: roll, pitch, yaw), the cube's linear
(3) and angular (3) velocity (the root's frame), the grip point's velocity (3), the gripper's speed (1: opening per
second).

action: ``Box(-1, 1, (4,))``: the grip point's target is where it stands plus ``ee_step`` (0.05 m) x the first three
(panda-gym's convention), kept above the table and within the workspace, the gripper's orientation held as it was
at the ready configuration (pointing down); the fourth is the gripper's opening, -1 closed to 1 open, reached at
the fingers' velocity limit with their URDF effort (Push-v0 holds the gripper closed, as FetchPush blocks it).
Each step is ``step_time`` (0.04 s: 20 of MuJoCo's steps) of physics, the arm's servos tracking the joint targets
that damped least squares gives for the target (two iterations on the grip point's 6-row Jacobian, from where the
joints stand).

Episode: the arm at its ready configuration (physics.workspace: the gripper pointing down READY_HEIGHT over the
table's middle, open), the cube on the table within ``obj_range`` (0.3 m square) of the middle, the goal within
``goal_range`` (0.3 m) of it, on the table (push) or up to ``goal_height`` (0.2 m) above it (pick and place), both
drawn from the env's np_random.
"""
from __future__ import annotations

import math
import warnings

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from robot_ai.physics.model import PhysicsError, build_physics, free_velocity
from robot_ai.physics.workspace import Workspace, hand_gripper, workspace
from robot_ai.reach.arm import Arm, ReachError
from robot_ai.reach.env import vector_reset_args
from robot_ai.reach.model import load_model

TASKS = ('push', 'pick_and_place')
OBJECT = 'object'
EE_STEP = 0.05              # m: the grip point's target moves at most this per step
ANGULAR_WEIGHT = 0.2        # m per rad: the orientation's rows in the least squares
DAMPING = 0.05
IK_ITERATIONS = 2
TABLE_MARGIN = 0.005        # m: the fingertips' lowest target above the table
PUSH_BELOW = 0.005          # m: a push's closed hand reaches at least this far under the cube's middle (where it can)
AJAR = 0.015                # m: a slow gripper's open fingers clear the cube by this on either side, no wider
SLOW_GRIPPER = 0.25         # s: a gripper slower than this to close onto the cube from wide open is slow (the Gen3
                            # lite's took 1.1 s, half the episode; the Fetch's 0.6; the Panda's 0.1)


def rpy_of(m: np.ndarray) -> list[float]:
    """Roll, pitch, yaw of a rotation matrix, as the envs observe the cube."""
    return [math.atan2(m[2, 1], m[2, 2]), math.asin(-max(-1.0, min(1.0, m[2, 0]))), math.atan2(m[1, 0], m[0, 0])]


def _gripping_arm(tree, tip: str | None) -> Arm:
    """The arm to tip; with no tip given, the arm's end, or where it has no gripper below it (a tool frame beside
    the fingers: the PR2's r_gripper_tool_frame), the nearest link up its chain that has."""
    arm = Arm(tree, tip)
    if tip is not None:
        return arm
    fingers = {tree.joints[n].child for n in tree.finger_joints()}
    parents = {j.child: j.parent for j in tree.joints.values()}
    link = arm.tip
    while link in parents and not fingers & set(tree.subtree(link)):
        link = parents[link]
    return Arm(tree, link) if link != arm.tip and fingers & set(tree.subtree(link)) else arm


class ManipulationSetup:
    """The robot, its physics among a table and a cube, and the task's layout and spaces, shared by every world of
    an env (see the module's text for the kwargs). ReachError or PhysicsError of one line for what cannot be."""

    def __init__(self, task: str = 'push', model: str | None = None, xacro_args=None, tip: str | None = None,
                 object_size: float = 0.04, object_mass: float = 0.1, distance_threshold: float = 0.05,
                 reward_type: str = 'sparse', obj_range: float = 0.3, goal_range: float = 0.3,
                 goal_height: float = 0.2, step_time: float = 0.04, urdf: str | None = None):
        if task not in TASKS:
            raise ValueError(f'task must be one of {TASKS}, got {task!r}')
        if reward_type not in ('sparse', 'dense'):
            raise ValueError(f"reward_type must be 'sparse' or 'dense', got {reward_type!r}")
        for name, value in (('object_size', object_size), ('object_mass', object_mass),
                            ('distance_threshold', distance_threshold), ('step_time', step_time)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f'{name} must be a positive number, got {value!r}')
        for name, value in (('obj_range', obj_range), ('goal_range', goal_range), ('goal_height', goal_height)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f'{name} must be a number of metres, 0 or more, got {value!r}')
        if model is None and urdf is None:
            raise ReachError('give model= an arm with a gripper (a URDF or xacro file): the package\'s own arms have '
                             'none')
        self.task, self.reward_type = task, reward_type
        self.distance_threshold, self.object_size = float(distance_threshold), float(object_size)
        self.obj_range, self.goal_range, self.goal_height = float(obj_range), float(goal_range), float(goal_height)
        self.robot = load_model(model, xacro_args, urdf)
        self.arm = _gripping_arm(self.robot.tree, tip)
        bare = build_physics(self.robot)
        self.space: Workspace = workspace(self.arm, bare)
        # what the layout says of the task on this arm (pick_place logs them; here, warnings)
        notes = [self.space.note] if self.space.note else []
        if self.space.grip.between:
            notes.append(f'{self.robot.tree.name}: the hand\'s own geometry ({", ".join(self.space.grip.between)}) '
                         f'stands between the open fingers past the grip point, where an object meets it '
                         f'(franka_description\'s *_sc links are self-collision capsules: gazebo:=true leaves them '
                         f'out)')
        self.notes: tuple[str, ...] = tuple(notes)
        for note in self.notes:
            warnings.warn(note, stacklevel=2)
        centre, top = self.space.centre, self.space.table_top
        self.object_mass = float(object_mass)
        cube = self.cube([centre[0], centre[1], top + object_size / 2])
        home = dict(zip(self.arm.joints, self.space.ready.tolist()))
        self.physics = build_physics(self.robot, obstacles=[self.table()], objects=[cube], home=home)
        if any('the robot touches' in n for n in self.physics.notes):
            raise PhysicsError(f'{self.robot.tree.name}: at the ready configuration the robot touches the table or '
                               f'the cube ({self.physics.notes[-1]})')
        self.step_time = float(step_time)
        self.substeps = max(1, int(round(step_time / self.physics.model.opt.timestep)))
        self._layout()
        self.ready_grip = self.grip_points(self.space.ready[:, None])[0][:, 0]     # where every episode starts
        self.action_space = spaces.Box(-1.0, 1.0, (4,), dtype=np.float32)
        goal = spaces.Box(-np.inf, np.inf, (3,), dtype=np.float64)
        self.observation_space = spaces.Dict({'achieved_goal': goal, 'desired_goal': goal,
                                              'observation': spaces.Box(-np.inf, np.inf, (23,), dtype=np.float64)})

    def _layout(self) -> None:
        """MuJoCo addresses: the arm's joints and servos, the gripper's, the cube's free joint."""
        import mujoco
        model, physics = self.physics.model, self.physics
        self.q_address = np.array([physics.qpos_address(n) for n in self.arm.joints])
        self.arm_actuators = np.array([physics.actuated.index(n) for n in self.arm.joints])
        self.gripper = hand_gripper(self.arm, physics)
        self.grip_actuators = np.array([physics.actuated.index(n) for n in self.gripper])
        ranges = model.actuator_ctrlrange[self.grip_actuators]
        low, high = ranges[:, 0].copy(), ranges[:, 1].copy()
        self.grip_closed, self.grip_open = (low, high) if self.space.grip.open_high else (high, low)
        self.grip_speed = np.array([physics.gripper_speed[physics.gripper.index(n)] for n in self.gripper])
        self.grip_q = np.array([physics.qpos_address(n) for n in self.gripper])
        self.finger_q = int(self.grip_q[0])
        self.actuated_q = np.array([physics.qpos_address(n) for n in physics.actuated])
        self.object_body, self.object_q, self.object_v = physics.object_addresses(OBJECT)
        self.tip_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, self.arm.tip)
        centre, top = self.space.centre, self.space.table_top
        reach = max(self.obj_range, self.goal_range) / 2 + 0.1
        grip = self.space.grip                  # a push's gripper is closed throughout: its hand as it is then
        beyond = grip.closed_beyond if self.task == 'push' else grip.beyond
        self.low = np.array([centre[0] - reach, centre[1] - reach, top + TABLE_MARGIN + beyond])
        self.high = np.array([centre[0] + reach, centre[1] + reach, top + self.goal_height + 0.2])
        half = self.object_size / 2             # where a push starts behind the cube: the hand clear of it
        self.behind = half + grip.radius(half + 0.01) + 0.015
        # how far under the cube's middle the grip point pushes: the closed hand's lowest point PUSH_BELOW under it
        self.sink = max(0.0, PUSH_BELOW - grip.closed_beyond)
        rate = float(np.min(self.grip_speed / np.maximum(np.abs(self.grip_open - self.grip_closed), 1e-9)))
        closing = (1.0 - grip.ajar(self.object_size, half)) / rate if rate > 0 else np.inf
        self.slow_gripper = bool(closing > SLOW_GRIPPER)
        self.ajar = self.ajar_for(self.object_size, half)        # the cube gripped at its middle

    def table(self) -> dict:
        """The table, as an obstacle (motion.body's YAML): its top table_top, under the whole workspace."""
        half = max(self.obj_range, self.goal_range) / 2 + 0.15
        centre, top = self.space.centre, self.space.table_top
        return {'box': [2 * half, 2 * half, 0.04], 'position': [float(centre[0]), float(centre[1]), top - 0.02],
                'name': 'table'}

    def cube(self, position, name: str = OBJECT) -> dict:
        """The task's cube at position, as a loose object (physics.model's YAML)."""
        return {'box': [self.object_size] * 3, 'position': [float(x) for x in position], 'mass': self.object_mass,
                'name': name}

    def grip_position(self, opening: float) -> float:
        """The gripper's first joint (a gripper command's position, m or rad) at opening (0 closed, 1 open)."""
        return float(self.grip_closed[0] + opening * (self.grip_open[0] - self.grip_closed[0]))

    def ajar_for(self, width: float, above: float) -> float:
        """How far the scripted expert opens the gripper (0 closed, 1 open) for an object width across whose top
        stands above over the grip point: a slow gripper AJAR wider than the object on either side, another fully."""
        return self.space.grip.ajar(width + 2 * AJAR, above) if self.slow_gripper else 1.0

    def expert(self, observation, desired_goal, ajar: float | None = None) -> np.ndarray:
        """The scripted expert's actions (physics.expert) for this arm: its push start, lowest grip point, fingers'
        reach, and how far it opens them (0 closed, 1 open; None: ajar_for the cube)."""
        from robot_ai.physics.expert import expert_actions
        return expert_actions(observation, desired_goal, self.task, behind=self.behind, lowest=self.low[2],
                              sink=self.sink, reach=self.space.grip.beyond,
                              ajar=self.ajar if ajar is None else ajar)

    # --------------------------------------------------------------------------------------------- the task
    def compute_reward(self, achieved_goal, desired_goal, info=None) -> np.ndarray:
        d = np.linalg.norm(np.asarray(achieved_goal, dtype=float) - np.asarray(desired_goal, dtype=float), axis=-1)
        if self.reward_type == 'sparse':
            return -(d > self.distance_threshold).astype(np.float64)
        return -d

    def sample(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """(the cube's start, the goal), drawn from rng."""
        centre, top, half = self.space.centre, self.space.table_top, self.object_size / 2
        cube = np.array([*(centre[:2] + rng.uniform(-self.obj_range / 2, self.obj_range / 2, 2)), top + half])
        goal = np.array([*(centre[:2] + rng.uniform(-self.goal_range / 2, self.goal_range / 2, 2)), top + half])
        if self.task == 'pick_and_place':
            goal[2] += rng.uniform(0.0, self.goal_height)
        return cube, goal

    # -------------------------------------------------------------------------------------------- the worlds
    def new_data(self):
        import mujoco
        return mujoco.MjData(self.physics.model)

    def start(self, data, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, float]:
        """A new episode in data, drawn from rng: (the goal, the grip point, the gripper's first joint)."""
        cube, goal = self.sample(rng)
        self.place(data, cube)
        return goal, self.ready_grip.copy(), float(data.qpos[self.finger_q])

    def place(self, data, cube: np.ndarray) -> None:
        """data at the ready configuration, at rest, every servo holding its joint there, the gripper's joints open
        (closed for push), the cube at cube."""
        import mujoco
        data.qpos[:] = self.physics.model.qpos0
        data.qvel[:] = 0.0
        data.qpos[self.q_address] = self.space.ready
        opening = self.grip_closed if self.task == 'push' else self.grip_open
        data.qpos[self.grip_q] = opening
        self.physics.follow_mimics(data)
        data.ctrl[:] = data.qpos[self.actuated_q]
        data.qpos[self.object_q:self.object_q + 7] = [*cube, 1.0, 0.0, 0.0, 0.0]
        data.qacc_warmstart[:] = 0.0
        data.time = 0.0
        mujoco.mj_forward(self.physics.model, data)

    def grip_points(self, q_t: np.ndarray) -> tuple[np.ndarray, np.ndarray, list, list]:
        """(grip points (3, N), rotations (3, 3, N), axes, origins) of joint positions q_t (n, N)."""
        tip, rotation, axes, origins = self.arm.pose_t(q_t)
        offset = self.space.grip.offset
        grip = tip + rotation[:, 0] * offset[0] + rotation[:, 1] * offset[1] + rotation[:, 2] * offset[2]
        return grip, rotation, axes, origins

    def joint_targets(self, q_t: np.ndarray, target_t: np.ndarray, held: np.ndarray | None = None) -> np.ndarray:
        """Joint targets (n, N) that put the grip points at target_t (3, N), the gripper as it was at the ready
        configuration (or as held, a 3x3 rotation of the tip): IK_ITERATIONS of damped least squares from q_t."""
        held = self.space.rotation if held is None else held
        for _ in range(IK_ITERATIONS):
            grip, rotation, axes, origins = self.grip_points(q_t)
            turn = sum(np.cross(rotation[:, k].T, held[:, k]).T for k in range(3)) / 2.0
            dx = np.concatenate([target_t - grip, ANGULAR_WEIGHT * turn])
            jac = self.arm.jacobian6_t(grip, axes, origins, angular_weight=ANGULAR_WEIGHT)
            q_t = self.arm.move_t(q_t, jac, dx, DAMPING)
        return q_t

    def check_actions(self, actions: np.ndarray) -> np.ndarray:
        """actions (N, 4) clipped to [-1, 1]; ValueError for a wrong shape, NaN or infinite values."""
        a = np.asarray(actions, dtype=np.float64)
        if a.ndim != 2 or a.shape[1] != 4 or not np.isfinite(a).all():
            raise ValueError(f'an action is 4 finite numbers (dx, dy, dz, gripper), got {a.tolist()}')
        return np.clip(a, -1.0, 1.0)

    def commands(self, q_t: np.ndarray, grips: np.ndarray, actions: np.ndarray,
                 grip_now: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(the arms' joint targets (n, N), the gripper servos' targets (N, g)) of one step of N worlds: their
        joints q_t (n, N), grip points grips (N, 3) as last observed, actions (N, 4) checked and the gripper servos'
        targets now grip_now (N, g). The joints by damped least squares for all at once; the gripper toward the
        action's opening (closed for push) at most its joints' velocity limits over the step."""
        targets = np.clip(grips + EE_STEP * actions[:, :3], self.low, self.high)
        joints = self.joint_targets(q_t, np.ascontiguousarray(targets.T))
        if self.task == 'push':
            openings = np.broadcast_to(self.grip_closed, (len(actions), len(self.grip_closed)))
        else:
            openings = self.grip_closed + (actions[:, 3:4] + 1.0) / 2.0 * (self.grip_open - self.grip_closed)
        reach = self.grip_speed * self.step_time
        return joints, np.clip(openings, grip_now - reach, grip_now + reach)

    def act(self, datas: list, grips: np.ndarray, actions: np.ndarray) -> None:
        """One step of the worlds datas (N), their grip points grips (N, 3) as last observed, under actions (N, 4)
        checked: commands' targets, then step_time of physics each."""
        import mujoco
        q_t = np.stack([d.qpos[self.q_address] for d in datas], axis=1)
        joints, grip = self.commands(q_t, grips, actions, np.stack([d.ctrl[self.grip_actuators] for d in datas]))
        for i, data in enumerate(datas):
            data.ctrl[self.arm_actuators] = joints[:, i]
            data.ctrl[self.grip_actuators] = grip[i]
            mujoco.mj_step(self.physics.model, data, nstep=self.substeps)

    def observe(self, data, last_grip: np.ndarray, last_finger: float) -> tuple[np.ndarray, np.ndarray]:
        """(observation (23,), grip point) of data as its last step left it (its bodies' poses brought up to date:
        mj_step leaves them one MuJoCo step behind the joints); last_grip, last_finger: the step before's, for
        velocities."""
        import mujoco
        mujoco.mj_kinematics(self.physics.model, data)
        return self.observation(data.xpos[self.tip_body], data.xmat[self.tip_body].reshape(3, 3),
                                data.xpos[self.object_body], data.xmat[self.object_body].reshape(3, 3),
                                float(data.qpos[self.finger_q]), free_velocity(data, self.object_body, self.object_v),
                                last_grip, last_finger)

    def observation(self, tip, tip_rotation, cube, cube_rotation, finger: float, velocity, last_grip,
                    last_finger: float) -> tuple[np.ndarray, np.ndarray]:
        """(observation (23,), grip point) of the tip's pose, the cube's pose (positions, 3x3 rotations; the root's
        frame), the gripper's first joint, the cube's velocity (6: linear, angular, the root's frame) and the step
        before's grip point and gripper joint: the envs' over MuJoCo and over ROS both observe with it."""
        grip = tip + tip_rotation @ self.space.grip.offset
        cube = np.array(cube, dtype=float)
        span = self.grip_open[0] - self.grip_closed[0]
        observation = np.concatenate([grip, cube, cube - grip, [(finger - self.grip_closed[0]) / span],
                                      rpy_of(cube_rotation), velocity[:3], velocity[3:],
                                      (grip - last_grip) / self.step_time,
                                      [(finger - last_finger) / span / self.step_time]])
        return observation, grip


class ManipulationEnv(gymnasium.Env):
    """One world of a ManipulationSetup (see the module's text)."""

    metadata = {'render_modes': []}

    def __init__(self, task: str = 'push', setup: ManipulationSetup | None = None, **kwargs):
        self.setup = setup if setup is not None else ManipulationSetup(task, **kwargs)
        self.action_space = self.setup.action_space
        self.observation_space = self.setup.observation_space
        self.data = self.setup.new_data()
        self._goal: np.ndarray | None = None
        self._grip = np.zeros(3)
        self._finger = 0.0

    def compute_reward(self, achieved_goal, desired_goal, info=None):
        return self.setup.compute_reward(achieved_goal, desired_goal, info)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._goal, self._grip, self._finger = self.setup.start(self.data, self.np_random)
        obs = self._obs()
        return obs, {'is_success': self._success(obs)}

    def step(self, action):
        if self._goal is None:
            raise ResetNeeded('Cannot call env.step() before calling env.reset()')
        a = self.setup.check_actions(np.reshape(action, (1, -1)))
        self.setup.act([self.data], self._grip[None], a)
        obs = self._obs()
        info = {'is_success': self._success(obs)}
        reward = float(self.compute_reward(obs['achieved_goal'], obs['desired_goal'], info))
        return obs, reward, False, False, info

    def _obs(self) -> dict[str, np.ndarray]:
        observation, self._grip = self.setup.observe(self.data, self._grip, self._finger)
        self._finger = float(self.data.qpos[self.setup.finger_q])
        return {'achieved_goal': observation[3:6].copy(), 'desired_goal': self._goal.copy(),
                'observation': observation}

    def _success(self, obs) -> bool:
        return bool(np.linalg.norm(obs['achieved_goal'] - obs['desired_goal']) <= self.setup.distance_threshold)


class ManipulationVectorEnv(VectorEnv):
    """num_envs worlds of one ManipulationSetup stepped together (one least-squares pass for all, then each world's
    physics), equal bit for bit to gymnasium's SyncVectorEnv over ManipulationEnvs (autoreset next-step,
    reset(seed=s) seeds env i with s + i, options['reset_mask'] resets those only). The kwargs are
    ManipulationEnv's."""

    metadata = {'render_modes': [], 'autoreset_mode': AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, task: str = 'push', max_episode_steps: int = 50,
                 setup: ManipulationSetup | None = None, **kwargs):
        if not (isinstance(num_envs, int) and num_envs >= 1):
            raise ValueError(f'num_envs must be a whole number, 1 or more, got {num_envs!r}')
        self.setup = setup if setup is not None else ManipulationSetup(task, **kwargs)
        self.num_envs = num_envs
        self.max_episode_steps = int(max_episode_steps)
        self.single_action_space = self.setup.action_space
        self.single_observation_space = self.setup.observation_space
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.datas = [self.setup.new_data() for _ in range(num_envs)]
        self._rngs: list[np.random.Generator | None] = [None] * num_envs
        self._goal = np.zeros((num_envs, 3))
        self._grip = np.zeros((num_envs, 3))
        self._finger = np.zeros(num_envs)
        self._obs = np.zeros((num_envs, 23))
        self._elapsed = np.zeros(num_envs, dtype=int)
        self._started = np.zeros(num_envs, dtype=bool)
        self._autoreset = np.zeros(num_envs, dtype=bool)

    def compute_reward(self, achieved_goal, desired_goal, info=None):
        return self.setup.compute_reward(achieved_goal, desired_goal, info)

    def reset(self, *, seed=None, options=None):
        seeds, mask = vector_reset_args(self.num_envs, seed, options)
        chosen = np.flatnonzero(mask)
        self._reset_envs(chosen, seeds)
        self._autoreset[chosen] = False
        infos = {'is_success': np.where(mask, self._successes(), False), '_is_success': mask.copy()}
        return self._observations(), infos

    def _reset_envs(self, rows, seeds) -> None:
        for i in rows:
            if seeds[i] is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(seeds[i])
            self._goal[i], self._grip[i], self._finger[i] = self.setup.start(self.datas[i], self._rngs[i])
            self._observe(i)
            self._elapsed[i] = 0
            self._started[i] = True

    def _observe(self, i: int) -> None:
        self._obs[i], self._grip[i] = self.setup.observe(self.datas[i], self._grip[i], self._finger[i])
        self._finger[i] = self.datas[i].qpos[self.setup.finger_q]

    def _observations(self) -> dict[str, np.ndarray]:
        return {'achieved_goal': self._obs[:, 3:6].copy(), 'desired_goal': self._goal.copy(),
                'observation': self._obs.copy()}

    def _successes(self) -> np.ndarray:
        return np.linalg.norm(self._obs[:, 3:6] - self._goal, axis=1) <= self.setup.distance_threshold

    def step(self, actions):
        if not self._started.all():
            raise ResetNeeded('Cannot call env.step() before calling env.reset()')
        actions = np.asarray(actions, dtype=np.float64)
        if actions.shape != self.action_space.shape:
            raise ValueError(f'actions must have shape {self.action_space.shape}, got {actions.shape}')
        stepping = ~self._autoreset
        rows = np.flatnonzero(stepping)
        if len(rows):
            a = self.setup.check_actions(actions[rows])
            self.setup.act([self.datas[i] for i in rows], self._grip[rows], a)
            for i in rows:
                self._observe(i)
        resetting = np.flatnonzero(self._autoreset)
        if len(resetting):
            self._reset_envs(resetting, [None] * self.num_envs)
        self._elapsed[rows] += 1
        success = self._successes()
        rewards = np.where(stepping, self.compute_reward(self._obs[:, 3:6], self._goal), 0.0)
        terminations = np.zeros(self.num_envs, dtype=bool)
        truncations = stepping & (self._elapsed >= self.max_episode_steps)
        self._autoreset = truncations.copy()
        infos = {'is_success': success, '_is_success': np.ones(self.num_envs, dtype=bool)}
        return self._observations(), rewards, terminations, truncations, infos
