#!/usr/bin/env python3
"""forward_kinematics on bad input, a late robot_description and ~reload: it keeps running and keeps
publishing frames equal to robot_state_publisher's afterwards."""
import os
import random
import sys
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

sys.path.insert(0, os.path.dirname(os.path.realpath(__file__)))
from fk_helpers import mimic_chain, robot_path  # noqa: E402
from ros_helpers import NodePair, rotation_angle, to_matrix, wait_for  # noqa: E402

UR5 = ['shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint', 'wrist_2_joint',
       'wrist_3_joint']


def read(name):
    with open(robot_path(name)) as f:
        return f.read()


def wide_tree(joints: int) -> str:
    """A URDF of `joints` revolute joints, each child under one of the 50 links before it, with inertias and
    limits, random origins: about 370 bytes a joint, like a big real robot description."""
    r = random.Random(0)
    parts = ['<robot name="wide"><link name="l0"/>']
    for i in range(1, joints + 1):
        xyz = ' '.join(f'{r.random():.6f}' for _ in range(3))
        rpy = ' '.join(f'{r.random():.6f}' for _ in range(3))
        parts.append(f'<link name="l{i}"><inertial><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" '
                     f'iyz="0" izz="0.1"/></inertial></link><joint name="j{i}" type="revolute"><parent '
                     f'link="l{r.randrange(max(0, i - 50), i)}"/><child link="l{i}"/><origin xyz="{xyz}" '
                     f'rpy="{rpy}"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>')
    return ''.join(parts) + '</robot>'


def memory_mib(pid: int) -> dict:
    """VmRSS and VmHWM (peak) of a process, MiB."""
    with open(f'/proc/{pid}/status') as f:
        fields = dict(line.split(':', 1) for line in f)
    return {k: int(fields[k].split()[0]) / 1024 for k in ('VmRSS', 'VmHWM')}


class TestForwardKinematicsNode(unittest.TestCase):

    def assert_same_as_rsp(self, pair, stamp, root, tip):
        for rec in pair.recorders.values():
            self.assertTrue(wait_for(lambda: rec.buffer.can_transform(root, tip, stamp), 5))
        want = to_matrix(pair.recorders['rsp'].buffer.lookup_transform(root, tip, stamp))
        got = to_matrix(pair.recorders['fk'].buffer.lookup_transform(root, tip, stamp))
        self.assertLess(np.abs(got[:3, 3] - want[:3, 3]).max(), 1e-9)
        self.assertLess(rotation_angle(got, want), 1e-9)

    def test_bad_input_is_dropped_and_node_keeps_publishing(self):
        pair = NodePair('/bad', read('ur5.urdf'))
        try:
            pair.wait_connected()
            fk = pair.recorders['fk']
            raw = rospy.Publisher('/bad/joint_states', JointState, queue_size=10)
            self.assertTrue(wait_for(lambda: raw.get_num_connections() >= 2, 10))
            dropped = []
            for names, pos in ((UR5, [0.1, float('nan'), 0, 0, 0, 0]),        # NaN
                               (UR5, [0.1, float('inf'), 0, 0, 0, 0]),        # infinite
                               (UR5, [0.1, 0.2]),                             # fewer positions than names
                               (UR5[:2], [0.1, 0.2, 0.3])):                   # more positions than names
                msg = JointState(name=names, position=pos)
                msg.header.stamp = rospy.Time.now()
                raw.publish(msg)
                dropped.append(msg.header.stamp)
                rospy.sleep(0.05)
            # unknown names: the known ones are used
            rospy.sleep(0.05)
            stamp = pair.send(dict({n: 0.3 * i for i, n in enumerate(UR5)}, not_a_joint=1.0, another=2.0))
            self.assert_same_as_rsp(pair, stamp, 'base_link', 'tool0')
            self.assertFalse([s for s in dropped if s in fk.stamps], 'a bad message was published')
            # and a normal message after all that
            rospy.sleep(0.05)
            stamp = pair.send({n: -0.2 * i for i, n in enumerate(UR5)})
            self.assert_same_as_rsp(pair, stamp, 'base_link', 'tool0')
            self.assertTrue(pair.alive('fk'))
            raw.unregister()
        finally:
            pair.close()

    def test_waits_for_robot_description_then_reloads(self):
        pair = NodePair('/late', '', who=('fk',))
        rospy.delete_param('/late/robot_description')
        try:
            rospy.sleep(3.0)  # started with no robot_description: it waits, it does not exit
            self.assertTrue(pair.alive('fk'))
            rospy.set_param('/late/robot_description', read('ur5.urdf'))
            pair.wait_connected()
            stamp = pair.send({n: 0.1 for n in UR5})
            fk = pair.recorders['fk']
            self.assertTrue(wait_for(lambda: fk.buffer.can_transform('base_link', 'tool0', stamp), 10))

            rospy.wait_for_service('/late/fk/reload', 10)
            reload = rospy.ServiceProxy('/late/fk/reload', Trigger)
            rospy.set_param('/late/robot_description', '<robot name="broken"><link name="a"/>')
            res = reload()
            self.assertFalse(res.success)
            self.assertIn('kept the current robot', res.message)
            rospy.sleep(0.05)
            stamp = pair.send({n: 0.2 for n in UR5})  # still the UR5
            self.assertTrue(wait_for(lambda: fk.buffer.can_transform('base_link', 'tool0', stamp), 10))

            rospy.set_param('/late/robot_description', read('kuka_lwr_arm.urdf'))
            res = reload()
            self.assertTrue(res.success, res.message)
            self.assertIn('lwr', res.message.lower())
            rospy.sleep(0.05)
            stamp = pair.send({f'lwr_arm_{i}_joint': 0.0 for i in range(7)})
            self.assertTrue(wait_for(lambda: fk.buffer.can_transform('world_link', 'lwr_arm_7_link', stamp), 10))
            t = fk.buffer.lookup_transform('world_link', 'lwr_arm_7_link', stamp).transform.translation
            self.assertAlmostEqual(t.z, 1.3785, places=9)  # SOURCES.md: zero pose of the KUKA LWR
            self.assertTrue(pair.alive('fk'))
        finally:
            pair.close()

    def test_hostile_urdfs_params_and_names(self):
        """Issue 12: URDFs that ended the node (inf rpy, a 1,500-joint mimic chain), NaN in a URDF, bad
        parameters, a JointState with 100,000 unknown names: one clear line each, and the node keeps running."""
        tilted = ('<robot name="hostile"><link name="a"/><link name="b"/><joint name="elbow" type="revolute">'
                  '<parent link="a"/><child link="b"/><origin xyz="0 0 0" rpy="0 inf 0"/><axis xyz="0 0 1"/>'
                  '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>')
        pair = NodePair('/hostile', tilted, params={'publish_frequency': 'abc', 'use_tf_static': 'maybe'},
                        who=('fk',))
        try:
            rospy.sleep(3.0)  # the inf rpy is refused: it waits for a valid robot_description, it does not exit
            self.assertTrue(pair.alive('fk'))
            rospy.set_param('/hostile/robot_description', mimic_chain(1500))
            pair.wait_connected()
            fk = pair.recorders['fk']
            stamp = pair.send({'j0': 0.5})
            self.assertTrue(wait_for(lambda: stamp in fk.stamps, 20))
            # tf2 walks at most 1,000 frames of a chain: look at a link 900 joints down
            self.assertTrue(wait_for(lambda: fk.buffer.can_transform('l0', 'l900', stamp), 10))
            pose = fk.buffer.lookup_transform('l0', 'l900', stamp).transform.rotation  # 900 joints at 0.5 rad
            self.assertAlmostEqual(abs(pose.w), abs(np.cos(900 * 0.5 / 2)), places=6)

            rospy.wait_for_service('/hostile/fk/reload', 10)
            reload = rospy.ServiceProxy('/hostile/fk/reload', Trigger)
            for bad, message in ((tilted.replace('0 inf 0', '0 0 0').replace('xyz="0 0 0"', 'xyz="nan 0 0"'),
                                  "joint 'elbow': origin xyz must be finite numbers"),
                                 (42, 'holds int 42, not text'),
                                 (tilted, "joint 'elbow': origin rpy must be finite numbers")):
                rospy.set_param('/hostile/robot_description', bad)
                res = reload()
                self.assertFalse(res.success)
                self.assertIn(message, res.message)
                self.assertIn('kept the current robot', res.message)

            # 100,000 unknown names beside a known one: published, and the warning stays one short line
            names = [f'ghost_{i}' for i in range(100000)] + ['j0']
            rospy.sleep(0.1)
            msg = JointState(name=names, position=[0.0] * 100000 + [0.25])
            msg.header.stamp = rospy.Time.now()
            pair.pub.publish(msg)
            self.assertTrue(wait_for(lambda: msg.header.stamp in fk.stamps, 20))
            rospy.sleep(0.05)
            stamp = pair.send({'j0': 0.1})  # and the next message too
            self.assertTrue(wait_for(lambda: stamp in fk.stamps, 10))
            self.assertTrue(pair.alive('fk'))
        finally:
            pair.close()
        err = pair.procs['fk'].stderr.read().decode(errors='replace')
        self.assertIn("~publish_frequency must be a positive number (Hz), got 'abc': using 50.0", err)
        self.assertIn("~use_tf_static must be true or false, got 'maybe'", err)
        self.assertIn("origin rpy must be finite numbers", err)
        self.assertIn('100000 joints that are not in the URDF, ignored: ghost_0', err)
        self.assertIn('and 99990 more', err)
        self.assertLess(max(len(line) for line in err.splitlines()), 2000)
        self.assertNotIn('Traceback', err)

    def test_a_reload_storm_runs_one_reload_at_a_time_and_gives_memory_back(self):
        """Issue 18: 8 concurrent reloads of a 20,000-joint URDF took 88 s, peaked at 1.09 GB and kept 891 MB.
        Now requests that come during a reload share the next one, and each reload gives its memory back."""
        pair = NodePair('/storm', wide_tree(8000), who=('fk',))
        try:
            pair.wait_connected(120)
            pid = pair.procs['fk'].pid
            rospy.wait_for_service('/storm/fk/reload', 10)
            t0 = time.time()
            self.assertTrue(rospy.ServiceProxy('/storm/fk/reload', Trigger)().success)
            single = time.time() - t0
            before = memory_mib(pid)
            answers = []
            calls = [threading.Thread(target=lambda: answers.append(rospy.ServiceProxy('/storm/fk/reload', Trigger)()))
                     for _ in range(8)]
            t0 = time.time()
            for c in calls:
                c.start()
            for c in calls:
                c.join(300)
            storm = time.time() - t0
            after = memory_mib(pid)
            self.assertEqual(len(answers), 8)
            self.assertTrue(all(a.success for a in answers), [a.message for a in answers])
            self.assertLess(storm, 2 * single + 10, f'one reload {single:.1f} s, 8 at once {storm:.1f} s')
            self.assertLess(after['VmHWM'] - before['VmHWM'], 100, (before, after))  # no 8 parses at once
            self.assertLess(after['VmRSS'] - before['VmRSS'], 50, (before, after))   # and nothing kept
            stamp = pair.send({'j1': 0.3})
            self.assertTrue(wait_for(lambda: stamp in pair.recorders['fk'].stamps, 20))
        finally:
            pair.close()


if __name__ == '__main__':
    rospy.init_node('test_fk_node')
    rostest.rosrun('robot_ai', 'test_fk_node', TestForwardKinematicsNode)
