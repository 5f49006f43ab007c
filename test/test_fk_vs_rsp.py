#!/usr/bin/env python3
"""forward_kinematics against Debian's robot_state_publisher, the oracle, on the same URDF and joint states.

For every robot in ../shared/robots and for random trees, both nodes run side by side; each JointState is
sent to both, and root -> link is looked up at the message's stamp in a tf2 buffer per node: every link
present in both, equal to 1e-9 m and 1e-9 rad. Also: tf_prefix, explicit mimic values, publish_frequency
gating (the same messages accepted by both).
"""
import os
import sys
import unittest

import numpy as np
import rospy
import rostest

sys.path.insert(0, os.path.dirname(os.path.realpath(__file__)))
from fk_helpers import REFERENCE_ROBOTS, random_urdf, reference_link_poses, robot_path  # noqa: E402
from ros_helpers import NodePair, rotation_angle, tf2_name, to_matrix, wait_for  # noqa: E402
from robot_ai.kinematics import KinematicTree, prefix_frame  # noqa: E402

TOL = 1e-9
CASES = [0]


class TestAgainstRobotStatePublisher(unittest.TestCase):

    def compare(self, xml, configs, params=None, explicit_mimics=False):
        """Run both nodes on xml, send each configuration, compare every link at every stamp."""
        CASES[0] += 1
        ns = '/case%d' % CASES[0]
        tree = KinematicTree.from_xml_string(xml)
        prefix = (params or {}).get('tf_prefix', '')
        root = tf2_name(prefix_frame(prefix, tree.root))
        links = [tf2_name(prefix_frame(prefix, l)) for l in reference_link_poses(xml, {}) if l != tree.root]
        pair = NodePair(ns, xml, params)
        try:
            pair.wait_connected()
            stamps = []
            rng = np.random.default_rng(CASES[0])
            for q in (configs(tree, rng) if tree.active_joints else [{}]):
                if explicit_mimics:
                    for m in tree.mimic_joints:
                        if rng.random() < 0.5:
                            q[m] = float(rng.uniform(-1, 1))
                stamps.append(self.send_until_published(pair, q) if q else rospy.Time(0))
            checked = 0
            for stamp in stamps:
                for who, rec in pair.recorders.items():
                    ok = wait_for(lambda: all(rec.buffer.can_transform(root, l, stamp) for l in links), 10)
                    missing = [l for l in links if not rec.buffer.can_transform(root, l, stamp)]
                    self.assertTrue(ok, '%s: %s has no transform %s -> %s at %s; it published %s; frames %s' % (
                        ns, who, root, missing, stamp, rec.stamps, rec.frames()))
                for link in links:
                    want = to_matrix(pair.recorders['rsp'].buffer.lookup_transform(root, link, stamp))
                    got = to_matrix(pair.recorders['fk'].buffer.lookup_transform(root, link, stamp))
                    self.assertLess(np.abs(got[:3, 3] - want[:3, 3]).max(), TOL, '%s %s translation' % (ns, link))
                    self.assertLess(rotation_angle(got, want), TOL, '%s %s rotation' % (ns, link))
                    checked += 1
            # the same frames (floating subtrees included), none missing, none extra
            self.assertEqual(pair.recorders['fk'].frames(), pair.recorders['rsp'].frames(), ns)
            self.assertTrue(pair.alive('fk') and pair.alive('rsp'))
            return checked
        finally:
            pair.close()

    def send_until_published(self, pair, q, tries=3):
        """Send q until both nodes publish it. Both subscribe with a queue of 1 and may drop a message while
        busy (at start-up, say), as intended; a node that never publishes it fails the test."""
        for _ in range(tries):
            rospy.sleep(0.03)  # stamps over 1/publish_frequency apart
            stamp = pair.send(q)
            if wait_for(lambda: all(stamp in r.stamps for r in pair.recorders.values()), 3.0):
                return stamp
        self.fail('%s: not published by %s after %d tries' % (
            pair.ns, [w for w, r in pair.recorders.items() if stamp not in r.stamps], tries))

    @staticmethod
    def random_configs(n, scale=3.0):
        def configs(tree, rng):
            out = []
            for _ in range(n):
                q = {}
                for name in tree.active_joints:
                    big = tree.joints[name].type == 'continuous'
                    q[name] = float(rng.uniform(-1, 1) * (40.0 if big else scale))
                out.append(q)
            return out
        return configs

    def test_reference_robots(self):
        for name in REFERENCE_ROBOTS:
            with open(robot_path(name)) as f:
                xml = f.read()
            checked = self.compare(xml, self.random_configs(4))
            tree = KinematicTree.from_xml_string(xml)
            self.assertEqual(checked, (4 if tree.active_joints else 1) * (len(tree.link_poses()) - 1), name)

    def test_random_trees(self):
        for seed in range(10):
            self.compare(random_urdf(seed, n_links=16), self.random_configs(3), explicit_mimics=True)

    def test_panda_explicit_mimic_value_wins(self):
        with open(robot_path('panda.urdf')) as f:
            xml = f.read()
        self.compare(xml, lambda tree, rng: [dict({n: 0.3 for n in tree.active_joints},
                                                  panda_finger_joint1=0.02, panda_finger_joint2=0.035)])

    def test_tf_prefix(self):
        with open(robot_path('fixtures/frames_and_slashes.urdf')) as f:
            self.compare(f.read(), lambda tree, rng: [{}], params={'tf_prefix': 'pre'})
        self.compare(random_urdf(100, n_links=10), self.random_configs(2), params={'tf_prefix': '/robot1'})

    def test_publish_frequency_gating_like_rsp(self):
        with open(robot_path('ur5.urdf')) as f:
            xml = f.read()
        pair = NodePair('/gating', xml, {'publish_frequency': 20.0})
        try:
            pair.wait_connected()
            q = {'shoulder_pan_joint': 0.1, 'elbow_joint': 0.2}
            t0 = rospy.Time.now() - rospy.Duration(10)  # in the past: the gate never falls back on 'now'
            sent = [t0 + rospy.Duration(d) for d in (0.0, 0.01, 0.049, 0.05, 0.07, 0.2, 0.2)]
            for s in sent:
                pair.send(q, s)
                rospy.sleep(0.02)
            # only shoulder_pan: its own history decides (0.2 was last published for it too)
            pair.send({'shoulder_pan_joint': 0.3}, t0 + rospy.Duration(0.26))
            rospy.sleep(0.02)
            pair.send({'wrist_1_joint': 0.3}, t0 + rospy.Duration(0.21))  # first seen: always published
            rsp, fk = pair.recorders['rsp'], pair.recorders['fk']
            self.assertTrue(wait_for(lambda: len(rsp.stamps) >= 5 and len(fk.stamps) >= 5, 10))
            rospy.sleep(0.5)
            self.assertEqual([s.to_nsec() for s in fk.stamps], [s.to_nsec() for s in rsp.stamps])
            self.assertEqual(len(rsp.stamps), 5)  # 0, 0.05, 0.2, 0.26, 0.21
        finally:
            pair.close()


if __name__ == '__main__':
    rospy.init_node('test_fk_vs_rsp')
    rostest.rosrun('robot_ai', 'test_fk_vs_rsp', TestAgainstRobotStatePublisher)
