#!/usr/bin/env python3
"""Reach in the ROS graph: robot_ai/RosReach-v0 equals Reach-v0 (to 1e-9 m on every observation, identical
rewards and successes) on the UR5, on the PR2 (mimic joints in its chain) and on a xacro arm; leases and faults;
arm_sim's velocity limit and bad commands; reach_controller reaching points clicked in the root frame and in
another frame, saying when it cannot, and going home; an ONNX model loaded into it drives it, models of another env or
with foreign operators are refused."""
import os
import shutil
import signal
import subprocess
import sys
import time
import unittest

import gymnasium
import numpy as np
import rospy
import rostest
from geometry_msgs.msg import PointStamped
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray
from std_srvs.srv import Trigger

from robot_ai.envs import RosReachError  # the import registers robot_ai/RosReach-v0
from robot_ai.reach import ReachSetup  # the import registers robot_ai/Reach-v0

sys.path.insert(0, os.path.dirname(os.path.realpath(__file__)))
from doc_blocks import SHARED_ROBOTS, python_blocks, run_as_written  # noqa: E402

HERE = os.path.dirname(os.path.realpath(__file__))
PR2 = os.path.realpath(os.path.join(HERE, '..', '..', 'shared', 'robots', 'pr2.urdf'))
ARM7 = os.path.join(HERE, 'urdf', 'reach_arm7.urdf.xacro')


class TestReachRos(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        for ns in ('/arm_0', '/arm_1', '/pr2/arm_0', '/arm7/arm_0', '/controlled', '/world'):
            rospy.wait_for_service(f'{ns}/arm_sim/lease', 180)
        cls.log = []
        cls.log_sub = rospy.Subscriber('/rosout', Log, lambda m: cls.log.append((m.name, m.msg)), queue_size=1000)
        deadline = time.monotonic() + 240      # the controller trains ARS at its start (seconds)
        while not rospy.get_published_topics() or not any(t == '/controlled/reach_controller/distance'
                                                           for t, _ in rospy.get_published_topics()):
            assert time.monotonic() < deadline, 'reach_controller never started'
            time.sleep(0.5)

    def setUp(self):
        self.opened = []

    def tearDown(self):
        for env in self.opened:
            env.close()

    def ros(self, robot_ns='', **kwargs):
        env = gymnasium.make('robot_ai/RosReach-v0', robot_ns=robot_ns, timeout=kwargs.pop('timeout', 10.0), **kwargs)
        self.opened.append(env)
        return env

    # ------------------------------------------------------------------------------------ the env, against Reach-v0
    def assert_same_as_reach_v0(self, ros, ref, episodes=3, reward_type='sparse', watch=''):
        rng = np.random.default_rng(1)
        ee_step = ref.unwrapped.setup.ee_step
        worst, successes = 0.0, 0
        for episode in range(episodes):
            o1, i1 = ros.reset(seed=episode)
            o2, i2 = ref.reset(seed=episode)
            self.assertEqual(i1, i2)
            for t in range(60):       # past the 50-step limit: the truncation too
                if t % 2:     # a P-controller every other step: the arm reaches, clamps at limits, settles
                    a = np.clip((o1['desired_goal'] - o1['achieved_goal']) / ee_step, -1, 1).astype(np.float32)
                else:
                    a = rng.uniform(-1, 1, ros.action_space.shape).astype(np.float32)
                if watch and episode == 1 and t == 10:   # a read-only watcher of the sim's latched joint_states:
                    echo = subprocess.run(['rostopic', 'echo', '-n', '1', watch], capture_output=True, text=True,
                                          timeout=60)    # rospy re-sends it, bumping header.seq (issue 40)
                    self.assertIn('---', echo.stdout, echo.stderr)
                r1, r2 = ros.step(a), ref.step(a)
                for k in o2:
                    worst = max(worst, float(np.abs(r1[0][k] - r2[0][k]).max()))
                    self.assertEqual(r1[0][k].dtype, r2[0][k].dtype)
                if reward_type == 'sparse':
                    self.assertEqual(r1[1], r2[1])
                else:
                    self.assertAlmostEqual(r1[1], r2[1], delta=1e-9)
                self.assertEqual(r1[2:5], r2[2:5])
                successes += r1[4]['is_success']
                o1 = r1[0]
                if r1[3]:
                    break
        self.assertLess(worst, 1e-9)
        self.assertGreater(successes, 0)

    def test_env_equals_reach_v0_on_the_ur5(self):
        ros = self.ros('/arm_0')
        self.assert_same_as_reach_v0(ros, gymnasium.make('robot_ai/Reach-v0'), watch='/arm_0/joint_states/name')
        ros = self.ros('/arm_1', reward_type='dense')
        self.assert_same_as_reach_v0(ros, gymnasium.make('robot_ai/Reach-v0', reward_type='dense'),
                                     reward_type='dense')

    def test_env_equals_reach_v0_on_a_robot_with_mimic_joints(self):
        tip = 'r_gripper_r_finger_tip_link'       # the default tip is the arm's end now, not a finger (issue 38)
        ros = self.ros('/pr2/arm_0', tip=tip)
        arm = ros.unwrapped.arm
        self.assertTrue(any(arm.tree.joints[n].mimic for n in arm.chain), arm.chain)
        self.assert_same_as_reach_v0(ros, gymnasium.make('robot_ai/Reach-v0', model=PR2, tip=tip), episodes=2)

    def test_env_equals_reach_v0_on_a_xacro_arm(self):
        ros = self.ros('/arm7/arm_0')
        self.assertEqual(ros.unwrapped.arm.tip, 'tool')
        ref = gymnasium.make('robot_ai/Reach-v0', model=ARM7, xacro_args='scale:=2 tool:=true')
        self.assert_same_as_reach_v0(ros, ref)

    def test_envs_claim_free_arms_of_their_robot_and_a_held_one_is_an_error_naming_its_holder(self):
        ur5 = ReachSetup().model.path
        a, b = self.ros(model=ur5), self.ros(model=ur5)
        a.reset(seed=0)
        b.reset(seed=0)
        held = sorted([a.unwrapped.sim_namespace, b.unwrapped.sim_namespace])
        self.assertEqual(len(set(held)), 2)
        setup = ReachSetup()
        for env in (a, b):
            self.assertEqual(env.unwrapped.arm.tree.name, setup.arm.tree.name)   # a UR5 arm, not the PR2
        with self.assertRaises(RosReachError) as caught:
            self.ros(held[0]).reset(seed=0)
        self.assertIn('leased to', str(caught.exception))
        self.assertIn(held[0], str(caught.exception))
        with self.assertRaises(RosReachError) as caught:     # the PR2's arm holds another robot
            self.ros('/pr2/arm_0', model=ReachSetup().model.path).reset(seed=0)
        self.assertIn('another robot', str(caught.exception))

    # -------------------------------------------------------------------------------------------------- faults
    def test_no_sim_and_a_sim_not_in_lockstep_are_errors_naming_the_namespace(self):
        t = time.monotonic()
        with self.assertRaises(RosReachError) as caught:
            self.ros('/nobody', model=ReachSetup().model.path, timeout=1.5).reset(seed=0)
        self.assertLess(time.monotonic() - t, 1.5 + 5.0)
        self.assertIn('/nobody', str(caught.exception))
        self.assertIn('reach_gym.launch', str(caught.exception))
        with self.assertRaises(RosReachError) as caught:
            self.ros('/controlled').reset(seed=0)
        self.assertIn('/controlled', str(caught.exception))
        self.assertIn('lockstep', str(caught.exception))

    def start_victim(self, with_fk=True):
        """A lockstep arm_sim (and forward_kinematics) of the UR5 in /victim, as reach_gym.launch starts them."""
        rospy.set_param('/victim/robot_description', rospy.get_param('/arm_0/robot_description'))
        procs = [subprocess.Popen(['rosrun', 'robot_ai', 'arm_sim', '__ns:=/victim', '_lockstep:=true'],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=os.setsid)]
        if with_fk:
            procs.append(subprocess.Popen(['rosrun', 'robot_ai', 'forward_kinematics', '__ns:=/victim',
                                           '/tf:=/victim/tf', '/tf_static:=/victim/tf_static',
                                           '_ignore_timestamp:=true'],
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=os.setsid))
        rospy.wait_for_service('/victim/arm_sim/lease', 120)
        return procs

    def stop(self, procs):
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
            p.wait()

    def test_a_sim_killed_mid_episode_raises_within_the_timeout_and_every_call_after_it_too(self):
        procs = self.start_victim()
        try:
            deadline = time.monotonic() + 60
            while True:       # the victim's frames may take seconds on a loaded machine: a fresh env each try, as
                env = self.ros('/victim', timeout=2.0)      # gymnasium's env checker, whose first reset raised,
                try:                                        # fails the first step on its own state (a TypeError)
                    env.reset(seed=3)
                    break
                except RosReachError:
                    env.close()
                    self.assertLess(time.monotonic(), deadline)
            for _ in range(5):
                env.step(env.action_space.sample())
            self.stop(procs[:1])
            t = time.monotonic()
            with self.assertRaises(RosReachError) as caught:
                for _ in range(1000):
                    env.step(env.action_space.sample())
            self.assertLess(time.monotonic() - t, 2.0 + 5.0)
            self.assertIn('/victim', str(caught.exception))
            with self.assertRaises(RosReachError) as caught:
                env.step(env.action_space.sample())
            self.assertIn('call reset()', str(caught.exception))
        finally:
            self.stop(procs)

    def test_no_forward_kinematics_is_an_error_that_says_so(self):
        procs = self.start_victim(with_fk=False)
        try:
            with self.assertRaises(RosReachError) as caught:
                self.ros('/victim', timeout=2.0).reset(seed=0)
            self.assertIn('forward_kinematics', str(caught.exception))
        finally:
            self.stop(procs)

    # ------------------------------------------------------------------------------------------------ the arm_sim
    def test_the_docs_rosreach_blocks_run_as_written(self):
        """Issue 57: the python blocks of the docs that lease an arm (docs/envs/RosReach.md) run as written on
        reach_gym.launch's arms (sims:=2, as that page's roslaunch line), each in a process of its own."""
        blocks = [b for b in python_blocks() if b.needs_ros == 'reach' and not b.missing]
        self.assertGreaterEqual(len(blocks), 2, 'the test finds too few blocks')
        for block in blocks:
            self.assertEqual(run_as_written(block, str(SHARED_ROBOTS / 'ur5.urdf')), '')

    def test_arm_sim_moves_at_most_its_velocity_limits_and_ignores_bad_commands(self):
        states, velocities = [], []
        sub = rospy.Subscriber('/controlled/joint_states', JointState,
                               lambda m: (states.append((m.header.stamp.to_sec(), np.array(m.position))),
                                          velocities.append(np.array(m.velocity))))
        pub = rospy.Publisher('/controlled/joint_group_position_controller/command', Float64MultiArray,
                              queue_size=10)
        rospy.ServiceProxy('/controlled/reach_controller/home', Trigger)()     # no goal: the controller idles
        try:
            deadline = time.monotonic() + 30
            while pub.get_num_connections() == 0 and time.monotonic() < deadline:
                time.sleep(0.05)
            time.sleep(3.0)
            deadline = time.monotonic() + 60      # home reached: the arm at rest
            while not (len(states) > 2 and np.array_equal(states[-1][1], states[-2][1])) \
                    and time.monotonic() < deadline:
                time.sleep(0.1)
            start = states[-1][1]
            target = np.clip(start + 2.0, -np.pi + 0.1, np.pi - 0.1)
            states.clear()
            velocities.clear()
            pub.publish(Float64MultiArray(data=target.tolist()))
            deadline = time.monotonic() + 30
            # ticks, however slow a loaded machine is: 11 steps between stamps take 13 states (the last dropped)
            while len(states) < 14 and time.monotonic() < deadline:
                time.sleep(0.05)
            moving, said = list(states)[:-1], [np.abs(v).max() for v in list(velocities)[1:len(states) - 1] if len(v)]
            limit = float(np.max(ReachSetup().arm.velocity))        # the UR5's URDF velocity limits (3.2 rad/s)
            speeds = [np.abs(b - a).max() / (tb - ta) for (ta, a), (tb, b) in zip(moving, moving[1:]) if tb > ta]
            self.assertGreater(len(speeds), 10)
            self.assertLessEqual(max(speeds), limit * 1.05)      # never faster than the limit, in ROS time
            # it moves at the limit, not slower: a tick's step is the limit's (the wall clock's pace, a loaded
            # machine's late ticks, is not the sim's to keep: a tick is 1/rate of ROS time)
            self.assertGreater(len(said), 5)
            self.assertAlmostEqual(float(np.median(said)), limit, places=6)
            deadline = time.monotonic() + 60           # 0.64 s of ROS time at the limit, on a loaded machine longer
            while not np.allclose(states[-1][1], target, atol=1e-9, rtol=0) and time.monotonic() < deadline:
                time.sleep(0.1)
            np.testing.assert_allclose(states[-1][1], target, atol=1e-9)
            for bad in ([float('nan')] * 6, [0.1] * 5, [float('inf')] + [0.0] * 5):
                pub.publish(Float64MultiArray(data=bad))
            time.sleep(0.5)
            np.testing.assert_allclose(states[-1][1], target, atol=1e-9)     # ignored: the arm holds
        finally:
            sub.unregister()
            pub.unregister()

    def test_arm_sim_with_physics_tracks_a_command_reports_efforts_and_holds_a_bad_one_off(self):
        """~physics mujoco: joint_states carry efforts (the shoulder holds the arm's weight, the pan nothing), a
        command is tracked to within a milliradian, no joint faster than its velocity limit and a little, and a bad
        command is ignored."""
        states = []
        sub = rospy.Subscriber('/physics/joint_states', JointState,
                               lambda m: states.append((m.header.stamp.to_sec(), np.array(m.position),
                                                        np.array(m.effort))))
        pub = rospy.Publisher('/physics/joint_group_position_controller/command', Float64MultiArray, queue_size=10)
        try:
            deadline = time.monotonic() + 60
            while (pub.get_num_connections() == 0 or len(states) < 20) and time.monotonic() < deadline:
                time.sleep(0.05)
            _, start, effort = states[-1]
            self.assertEqual(len(effort), 6)
            self.assertLess(abs(effort[0]), 1.0)              # the pan turns no weight
            self.assertGreater(abs(effort[1]), 1.0)           # the shoulder holds the upper arm and all beyond
            target = start + np.array([0.5, 0.3, -0.3, 0.0, 0.0, 0.0])
            states.clear()
            pub.publish(Float64MultiArray(data=target.tolist()))
            deadline = time.monotonic() + 60
            while not (states and np.abs(states[-1][1] - target).max() < 1e-3) and time.monotonic() < deadline:
                time.sleep(0.1)
            self.assertLess(np.abs(states[-1][1] - target).max(), 1e-3)
            limit = ReachSetup().arm.velocity                 # the UR5's URDF velocity limits
            moving = list(states)
            speeds = [np.abs(b - a) / (tb - ta) for (ta, a, _), (tb, b, _) in zip(moving, moving[1:]) if tb > ta]
            self.assertTrue((np.max(speeds, axis=0) <= limit * 1.1).all(), np.max(speeds, axis=0))
            pub.publish(Float64MultiArray(data=[float('nan')] * 6))
            time.sleep(0.5)
            self.assertLess(np.abs(states[-1][1] - target).max(), 1e-3)       # ignored: the arm holds
        finally:
            sub.unregister()
            pub.unregister()

    # ------------------------------------------------------------------------------------------------ the controller
    def wait_for_log(self, words, since, timeout=30.0, node='/controlled/reach_controller'):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            said = [m for n, m in self.log[since:] if n == node and all(w in m for w in words)]
            if said:
                return said[0]
            time.sleep(0.1)
        self.fail(f'reach_controller never said {words}: {[m for n, m in self.log[since:]][-10:]}')

    def test_controller_reaches_clicked_points_in_two_frames_says_when_it_cannot_and_goes_home(self):
        clicks = rospy.Publisher('/clicked_point', PointStamped, queue_size=10)
        distances = []
        sub = rospy.Subscriber('/controlled/reach_controller/distance', Float64, lambda m: distances.append(m.data))
        try:
            deadline = time.monotonic() + 30
            while clicks.get_num_connections() == 0 and time.monotonic() < deadline:
                time.sleep(0.05)
            setup = ReachSetup()
            goal = setup.arm.tip_positions(np.array([0.6, -1.2, 1.3, -0.4, 0.8, 0.0]))
            for frame, point in (('base_link', goal), ('tool0', np.array([0.05, -0.1, 0.15]))):
                since = len(self.log)
                msg = PointStamped(point=type(PointStamped().point)(*point))
                msg.header.frame_id = frame
                clicks.publish(msg)
                said = self.wait_for_log(['reached'], since)
                self.assertTrue(said.startswith('reached ('), said)
                self.assertLessEqual(float(said.rsplit('(', 1)[1].split()[0]), 0.05)   # said to 1 mm: 0.0496 is 0.050
                time.sleep(0.5)                # reached: it stays, and goes nowhere else (a retry from home, say)
                after = [m for n, m in self.log[since:] if n == '/controlled/reach_controller']
                self.assertFalse([m for m in after if 'going home' in m], after)
            since = len(self.log)
            msg = PointStamped(point=type(PointStamped().point)(3.0, 0.0, 0.2))
            msg.header.frame_id = 'base_link'
            clicks.publish(msg)
            said = self.wait_for_log(['not reached: closest'], since)
            closest = float(said.split('closest ')[1].split()[0])
            self.assertGreater(closest, 1.5)          # the UR5 reaches about 1 m: 3 m is 2 m out
            self.assertIn('beyond the arm\'s reach: 3.007 m from base_link', said)   # the reason, and no retry
            self.assertIn('holding at the closest', said)
            time.sleep(2.0)                           # back at its closest configuration, and still there
            self.assertLess(abs(distances[-1] - closest), 0.002, distances[-20:])
            self.assertLess(max(distances[-10:]) - min(distances[-10:]), 0.001, distances[-10:])
            answer = rospy.ServiceProxy('/controlled/reach_controller/home', Trigger)()
            self.assertTrue(answer.success)
            deadline = time.monotonic() + 20.0           # at a quarter of the velocity limits (~velocity_scale)
            while True:
                joints = rospy.wait_for_message('/controlled/joint_states', JointState, 10)
                if np.abs(np.array(joints.position) - setup.home).max() < 1e-6 or time.monotonic() > deadline:
                    break
                time.sleep(0.2)
            np.testing.assert_allclose(joints.position, setup.home, atol=1e-6)
        finally:
            sub.unregister()
            clicks.unregister()

    def test_controller_goes_toward_home_first_when_a_joint_limit_blocks_the_way(self):
        """Issue 38: clicked one after another, goals fell where the last one had left a joint at its limit. The
        UR5's shoulder_pan at its +2 pi limit and a goal 0.6 rad further round: no policy gets there that way (the
        other joints cannot turn the tip about the base's axis). The env's limit recovery, in the controller as
        in-process: the first blocked command sends the arm, in joint space, to a configuration that reaches the
        goal; the log names the joint, and the goal is reached without waiting for a stall."""
        from robot_ai.srv import SetJointPositions
        setup = ReachSetup()
        start = setup.home.copy()
        pan = setup.arm.joints.index('shoulder_pan_joint')
        start[pan] = setup.arm.upper[pan]
        goal_q = start.copy()
        goal_q[pan] = setup.arm.upper[pan] + 0.6 - 2 * np.pi
        goal = setup.arm.tip_positions(goal_q)
        rospy.wait_for_service('/controlled/arm_sim/set_state', 30)
        answer = rospy.ServiceProxy('/controlled/arm_sim/set_state', SetJointPositions)(start.tolist())
        self.assertTrue(answer.success, answer.message)
        time.sleep(1.0)
        since = len(self.log)
        rospy.Publisher('/controlled/reach_controller/goal', PointStamped, queue_size=1, latch=True).publish(
            PointStamped(header=rospy.Header(frame_id='base_link'), point=type(PointStamped().point)(*goal)))
        said = self.wait_for_log(['going round in joint space'], since, timeout=60.0)
        self.assertIn('(shoulder_pan_joint at its limit)', said)
        said = self.wait_for_log(['reached'], since, timeout=120.0)       # reached, or not reached
        self.assertTrue(said.startswith('reached ('), said)
        after = [m for n, m in self.log[since:] if n == '/controlled/reach_controller']
        self.assertFalse([m for m in after if 'going home to try again' in m], after)     # no stall on the way

    def test_controller_in_a_world_never_commands_a_contact_and_says_what_blocks_it(self):
        """Issue 38: the KUKA LWR among a table and two boxes (test/world.yaml). Goals one after another: one inside a
        box is ignored in a line naming the box, the others reached or said blocked naming the links; every state the
        arm passes through (arm_sim's joint_states) is clear of the obstacles and of itself; rviz gets the boxes."""
        from robot_ai.reach.env import ReachSetup as Setup
        from visualization_msgs.msg import MarkerArray
        world = os.path.join(os.path.dirname(os.path.realpath(__file__)), 'world.yaml')
        setup = Setup(model=os.path.join(os.path.dirname(PR2), 'kuka_lwr_arm.urdf'), obstacles=world)
        deadline = time.monotonic() + 240      # its ARS trains at start, the body checked every step
        while not any(t == '/world/reach_controller/distance' for t, _ in rospy.get_published_topics()):
            self.assertLess(time.monotonic(), deadline, 'the world\'s reach_controller never started')
            time.sleep(0.5)
        markers = rospy.wait_for_message('/world/reach_controller/obstacle_markers', MarkerArray, 30)
        self.assertEqual([m.type for m in markers.markers], [1, 1, 1])
        states = []
        sub = rospy.Subscriber('/world/joint_states', JointState, lambda m: states.append(list(m.position)),
                               queue_size=1000)
        goals = rospy.Publisher('/world/reach_controller/goal', PointStamped, queue_size=1, latch=True)
        try:
            since = len(self.log)
            goals.publish(PointStamped(header=rospy.Header(frame_id='world_link'),
                                       point=type(PointStamped().point)(0.45, 0.1, 0.2)))
            said = self.wait_for_log(['ignored: it is inside'], since, node='/world/reach_controller')
            self.assertIn('box 1', said)
            outcomes = []
            for goal in ((0.3, -0.3, 0.4), (0.5, 0.1, 0.6), (-0.4, 0.2, 0.6), (0.2, 0.5, 0.3)):
                since = len(self.log)
                goals.publish(PointStamped(header=rospy.Header(frame_id='world_link'),
                                           point=type(PointStamped().point)(*goal)))
                said = self.wait_for_log(['reached'], since, timeout=90.0, node='/world/reach_controller')
                outcomes.append(said)
                if said.startswith('not reached'):
                    self.assertRegex(said, r'blocked .* by a collision \(lwr_arm_\d_link - (box \d|table)')
            self.assertGreaterEqual(sum(o.startswith('reached (') for o in outcomes), 3, outcomes)
        finally:
            sub.unregister()
        joints = setup.arm.joints
        names = rospy.wait_for_message('/world/joint_states', JointState, 10).name
        q = np.array([[s[names.index(n)] for n in joints] for s in states])
        self.assertGreater(len(q), 100)
        hit = setup.body.in_collision(q)
        self.assertFalse(hit.any(), [setup.body.contacts(c) for c in q[hit][:3]])

    def test_controller_takes_an_onnx_model_and_refuses_one_of_another_env_or_domain(self):
        """~load_policy with an ONNX model of the P-controller (a Clip of a MatMul, as an exported actor): it drives
        and reaches; a CartPole model and a model with a foreign operator are refused and the policy stays."""
        import tempfile
        import onnx_models
        from robot_ai.reach import learn
        from robot_ai.srv import LoadPolicy
        setup = ReachSetup()
        folder = tempfile.mkdtemp()
        self.addCleanup(shutil.rmtree, folder, True)
        meta = dict(env_id='robot_ai/Reach-v0', env_kwargs=dict(tip=setup.arm.tip, control='ee'),
                    robot=setup.model.tree.name, joints=list(setup.arm.joints))
        good = onnx_models.save(onnx_models.linear_clip(learn.p_controller(setup).weights.T, meta),
                                os.path.join(folder, 'p.onnx'))
        cartpole = onnx_models.save(onnx_models.cartpole_scores(np.ones(4, np.float32)),
                                    os.path.join(folder, 'cartpole.onnx'))
        foreign = onnx_models.linear_clip(learn.p_controller(setup).weights.T, meta)
        foreign.graph.node.append(onnx_models.helper.make_node('Run', ['obs'], ['x'], domain='com.evil'))
        foreign.opset_import.append(onnx_models.helper.make_opsetid('com.evil', 1))
        foreign = onnx_models.save(foreign, os.path.join(folder, 'foreign.onnx'))
        load = rospy.ServiceProxy('/controlled/reach_controller/load_policy', LoadPolicy)
        answer = load(good)
        self.assertTrue(answer.success, answer.message)
        self.assertTrue(rospy.get_param('/controlled/reach_controller/policy_info').startswith('ONNX policy from '))
        for path, words in ((cartpole, 'acts in CartPole-v1, not a reach env'),
                            (foreign, 'outside the standard domains: com.evil')):
            answer = load(path)
            self.assertFalse(answer.success)
            self.assertIn(words, answer.message)
        self.assertIn(good, rospy.get_param('/controlled/reach_controller/policy_info'))
        goal = setup.arm.tip_positions(np.array([-0.5, -1.0, 1.0, -0.2, 0.5, 0.0]))
        since = len(self.log)
        msg = PointStamped(point=type(PointStamped().point)(*goal))
        msg.header.frame_id = 'base_link'
        goals = rospy.Publisher('/controlled/reach_controller/goal', PointStamped, queue_size=1, latch=True)
        try:
            goals.publish(msg)
            said = self.wait_for_log(['reached'], since)
            self.assertTrue(said.startswith('reached ('), said)
        finally:
            goals.unregister()


if __name__ == '__main__':
    rospy.init_node('test_reach_ros')
    rostest.rosrun('robot_ai', 'reach_ros', TestReachRos, sys.argv)
