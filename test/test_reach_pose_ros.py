#!/usr/bin/env python3
"""Pose goals through ROS (reach_pose.test): reach_controller ~goal pose takes ~goal_pose in any frame tf knows and
the interactive marker's released pose; the tip it reports reached is there on /tf (position and orientation); each
goal is reached through ROS as its policy, played in-process through the same safety layer from the same start,
predicts (goal by goal, and about as fast); bad poses are refused in one line."""
import math
import os
import time
import unittest

import numpy as np
import rospy
import rostest
import tf2_ros
from geometry_msgs.msg import PoseStamped, TransformStamped
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from tf import transformations as tft
from visualization_msgs.msg import InteractiveMarkerFeedback, InteractiveMarkerUpdate

from ros_helpers import said_by
from robot_ai import ars
from robot_ai.reach import ReachEnv, ReachSetup, learn
from robot_ai.reach.safety import DEFAULT_VELOCITY_SCALE

HERE = os.path.dirname(os.path.realpath(__file__))
KUKA = os.path.realpath(os.path.join(HERE, '..', '..', 'shared', 'robots', 'kuka_lwr_arm.urdf'))
NODE = '/reach_controller'
GOALS = 8
PERIOD = 0.05                  # reach_controller's ~rate 20 Hz
PREDICTION_GOALS = 200         # reach_controller's own prediction (~predicted_success_rate): fresh goals from home
TURNED = tft.quaternion_about_axis(0.7, [0.3, -0.2, 0.9])      # the test's frame: turned and moved from the base
MOVED = [0.2, -0.1, 0.3]


def pose_msg(frame, goal):
    msg = PoseStamped()
    msg.header.frame_id = frame
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in goal[:3])
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in goal[3:])
    return msg


def in_turned_frame(goal):
    """goal (base frame) as the same pose in the test's frame: p' = R^T (p - t), q' = conj(R) q."""
    r = tft.quaternion_matrix(TURNED)[:3, :3]
    p = r.T @ (np.asarray(goal[:3]) - MOVED)
    q = tft.quaternion_multiply(tft.quaternion_conjugate(TURNED), goal[3:])
    return list(p) + list(q)


class TestReachPose(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        cls.setup = ReachSetup(KUKA, goal='pose')
        cls.log, cls.joints, cls.updates = [], {}, []
        cls.subs = [rospy.Subscriber('/rosout', Log, lambda m: cls.log.append((m.name, m.msg)), queue_size=1000),
                    rospy.Subscriber('/joint_states', JointState,
                                     lambda m: cls.joints.update(zip(m.name, m.position)), queue_size=10),
                    rospy.Subscriber(f'{NODE}/pose_marker/update', InteractiveMarkerUpdate, cls.updates.append,
                                     queue_size=100)]
        cls.tf = tf2_ros.Buffer(cache_time=rospy.Duration(30))
        cls.listener = tf2_ros.TransformListener(cls.tf)
        cls.static = tf2_ros.StaticTransformBroadcaster()
        t = TransformStamped()
        t.header.stamp, t.header.frame_id, t.child_frame_id = rospy.Time.now(), cls.setup.arm.base, 'test_goal_frame'
        t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = MOVED
        r = t.transform.rotation
        r.x, r.y, r.z, r.w = TURNED
        cls.static.sendTransform(t)
        # the node's own policy, trained here as it trains it at start (ARS is reproducible from its seed), and the
        # arm as the node's safety layer moves it (its default velocity_scale, one step a control period)
        cls.training = learn.train(dict(model=KUKA, tip=cls.setup.arm.tip, goal='pose'), seed=0,
                                   evaluate_episodes=1000)
        cls.moving = ReachEnv(KUKA, tip=cls.setup.arm.tip, goal='pose', velocity_scale=DEFAULT_VELOCITY_SCALE,
                              control_period=PERIOD)
        deadline = time.monotonic() + 400      # the controller trains ARS at its start (seconds; minutes loaded)
        while not any(n == NODE and 'reach_controller ready' in m for n, m in cls.log):
            assert time.monotonic() < deadline, 'reach_controller never started'
            time.sleep(0.5)
        cls.goal_pub = rospy.Publisher(f'{NODE}/goal_pose', PoseStamped, queue_size=1, latch=True)
        cls.feedback = rospy.Publisher(f'{NODE}/pose_marker/feedback', InteractiveMarkerFeedback, queue_size=1,
                                       latch=True)
        cls.home = rospy.ServiceProxy(f'{NODE}/home', Trigger)
        time.sleep(1.0)

    def wait_for_log(self, words, since, timeout=60.0):
        said = said_by(self.log, NODE, words, since, timeout)
        if said is None:
            self.fail(f'reach_controller never said {words}: {[m for n, m in self.log[since:] if n == NODE][-10:]}')
        return said

    def go_home(self):
        self.assertTrue(self.home().success)
        home = dict(zip(self.setup.arm.joints, self.setup.home))
        deadline = time.monotonic() + 60
        while max(abs(self.joints.get(n, 1e9) - v) for n, v in home.items()) > 1e-3:
            self.assertLess(time.monotonic(), deadline, 'the arm never came home')
            time.sleep(0.1)

    def tip_on_tf(self):
        t = self.tf.lookup_transform(self.setup.arm.base, self.setup.arm.tip, rospy.Time(0), rospy.Duration(2))
        p, r = t.transform.translation, t.transform.rotation
        return np.array([p.x, p.y, p.z]), np.array([r.x, r.y, r.z, r.w])

    def predicted(self, goal):
        """(reached, seconds) of the node's policy in-process, from home toward goal through the safety layer's
        model (Reach-v0 velocity_scale), as the node plays it: reached at the first step within both thresholds."""
        env = self.moving
        obs, info = env.reset(options={'goal': [float(v) for v in goal], 'q': self.setup.home.tolist()})
        space = env.observation_space
        for k in range(env.setup.episode_steps):
            if info['is_success']:
                return True, k * PERIOD
            action = self.training.policy.act_batch(ars.flatten_batch(space, {n: v[None] for n, v in obs.items()}))
            obs, _, _, _, info = env.step(action[0])
        return bool(info['is_success']), env.setup.episode_steps * PERIOD

    def outcome(self, goal, since):
        """(True, seconds) when the node says reached (and /tf's tip is then within both thresholds of goal, base
        frame), (False, None) when it says not reached."""
        said = self.wait_for_log([('reached',)], since, timeout=120)
        if said.startswith('not reached'):
            return False, None
        position, orientation = self.tip_on_tf()
        self.assertLess(np.linalg.norm(position - goal[:3]), 0.05 + 0.005, said)   # a step on since it was said
        angle = 2 * math.acos(min(1.0, abs(float(np.dot(orientation, goal[3:])))))
        self.assertLess(angle, 0.1 + 0.02, said)
        return True, float(said.split(' in ')[1].split(' s ')[0])

    def test_1_pose_goals_in_any_frame_are_reached_as_in_process(self):
        trained = rospy.get_param(f'{NODE}/success_rate')      # in-process, joints reached at once (1000 goals)
        rate = rospy.get_param(f'{NODE}/predicted_success_rate')   # through the node's own layer (200 goals)
        self.assertGreater(trained, 0.95)
        self.assertGreater(rate, 0.95, f'predicted through the layer: {rate}')
        # the policy and the layer's model here are the node's: the same figures to the last goal
        self.assertEqual(self.training.held_out.success_rate, trained, 'the node trained another policy')
        self.assertEqual(learn.evaluate(self.training.policy, self.moving.setup, PREDICTION_GOALS).success_rate, rate,
                         'the node predicts through another layer')
        rng = np.random.default_rng(11)
        rows = []
        # last, the goal a user's stalled on: from the straight-up (singular) home the arm turns first, its distance
        # growing for seconds at velocity_scale 0.25 (it was called not reached after a fixed 2 s)
        for i in range(GOALS + 1):
            goal = np.array([0.4, 0.3, 0.5, 0, 2 ** -0.5, 0, 2 ** -0.5]) if i == GOALS else \
                self.setup.goals_of(rng.uniform(self.setup.arm.lower, self.setup.arm.upper)[:, None])[:, 0]
            self.go_home()
            since = len(self.log)
            if i % 2:
                self.goal_pub.publish(pose_msg('test_goal_frame', in_turned_frame(goal)))
            else:
                self.goal_pub.publish(pose_msg(self.setup.arm.base, goal))
            said = self.wait_for_log([('goal (', 'orientation')], since)
            shown = [float(v) for v in said.split('(')[1].split(')')[0].split(',')]
            np.testing.assert_allclose(shown, goal[:3], atol=2e-3, err_msg=said)    # the frame converted
            rows.append((*self.predicted(goal), *self.outcome(goal, since)))
        table = '\n'.join(f'  goal {i}: in-process {"reached in %.2f s" % p_s if p else "not reached"}, through ROS '
                          f'{"reached in %.2f s" % r_s if r else "not reached"}' for i, (p, p_s, r, r_s) in
                          enumerate(rows))
        print(f'pose goals from home, in-process through the layer\'s model and through ROS (trained {trained:.3f}, '
              f'predicted {rate:.3f}):\n{table}')
        # goal by goal: a goal the policy reaches in-process is reached through ROS, about as fast (the node's steps
        # on a loaded machine come late: the arm moves in ROS time, the policy acts less often), and one it misses
        # in-process is missed (or reached only by the node's retry from home, later than the episode)
        for i, (p, p_s, r, r_s) in enumerate(rows):
            if p:
                self.assertTrue(r, f'goal {i}: reached in-process in {p_s:.2f} s, not through ROS\n{table}')
                self.assertTrue(p_s / 1.5 - 2.0 < r_s < 1.5 * p_s + 2.0,
                                f'goal {i}: through ROS not about as fast as in-process\n{table}')
            elif r:
                self.assertGreater(r_s, self.moving.setup.episode_steps * PERIOD,
                                   f'goal {i}: missed in-process, reached through ROS within the episode\n{table}')
        self.assertTrue(rows[GOALS][2], 'the goal from the singular home was not reached')

    def test_2_the_released_marker_is_the_goal_and_a_drag_is_not(self):
        rng = np.random.default_rng(5)
        goal = self.setup.goals_of(rng.uniform(self.setup.arm.lower, self.setup.arm.upper)[:, None])[:, 0]
        self.go_home()
        since = len(self.log)
        # the drag before the release, as rviz sends it: pose updates along the way, which are no goal (and raised
        # inside interactive_markers, a 'bad callback' traceback each, until the node took every feedback)
        home_tip = self.setup.goals_of(self.setup.home[:, None])[:, 0]
        for share in (0.25, 0.5, 0.75):
            drag = InteractiveMarkerFeedback(client_id='/rviz/InteractiveMarkers', marker_name='goal',
                                             event_type=InteractiveMarkerFeedback.POSE_UPDATE)
            drag.header.frame_id = self.setup.arm.base
            drag.pose = pose_msg(self.setup.arm.base, np.concatenate(
                (home_tip[:3] + share * (goal[:3] - home_tip[:3]), goal[3:]))).pose
            self.feedback.publish(drag)
            time.sleep(0.3)
        time.sleep(1.0)
        said = [m for n, m in self.log[since:] if n == NODE]
        self.assertFalse([m for m in said if m.startswith('goal (') or 'bad callback' in m], said)
        fb = InteractiveMarkerFeedback(client_id='/rviz/InteractiveMarkers', marker_name='goal',
                                       event_type=InteractiveMarkerFeedback.MOUSE_UP)
        fb.header.frame_id = self.setup.arm.base
        fb.pose = pose_msg(self.setup.arm.base, goal).pose
        self.feedback.publish(fb)
        said = self.wait_for_log([('goal (', 'orientation')], since)
        shown = [float(v) for v in said.replace(')', '(').split('(')[3].split(',')]
        np.testing.assert_allclose(shown, goal[3:], atol=2e-3, err_msg=said)
        self.outcome(goal, since)
        # the server moved the marker to the goal: rviz shows where it is
        deadline = time.monotonic() + 10
        while not any(p.name == 'goal' and abs(p.pose.position.x - goal[0]) < 1e-6 for u in self.updates
                      for p in u.poses + [m for m in u.markers]):
            self.assertLess(time.monotonic(), deadline, 'the marker did not move to the goal')
            time.sleep(0.1)

    def test_3_bad_poses_are_refused_in_one_line(self):
        since = len(self.log)
        self.goal_pub.publish(pose_msg(self.setup.arm.base, [0.3, 0.2, 0.4, 0, 0, 0, 0]))
        self.assertIn('is not a quaternion', self.wait_for_log([('goal pose ignored',)], since, 10))
        since = len(self.log)
        self.goal_pub.publish(pose_msg(self.setup.arm.base, [float('nan'), 0.2, 0.4, 0, 0, 0, 1]))
        self.wait_for_log([('ignored', 'finite')], since, 10)
        since = len(self.log)
        self.goal_pub.publish(pose_msg('no_such_frame', [0.3, 0.2, 0.4, 0, 0, 0, 1]))
        self.wait_for_log([('ignored', 'no transform')], since, 10)


if __name__ == '__main__':
    rospy.init_node('test_reach_pose', anonymous=True)
    rostest.rosrun('robot_ai', 'reach_pose', TestReachPose)
