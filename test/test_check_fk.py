#!/usr/bin/env python3
"""check_fk as a student runs it: it passes robot_state_publisher and forward_kinematics on every reference robot,
fails a node that rotates by euler angles axis * q on a URDF with a tilted axis (naming the link), passes that
same node where every axis is along x, y or z, and gives a clear verdict for a node that crashes or stays silent."""
import glob
import os
import subprocess
import sys
import time
import unittest

import rostest

sys.path.insert(0, os.path.dirname(os.path.realpath(__file__)))
from fk_helpers import ROBOTS_DIR  # noqa: E402

HERE = os.path.dirname(os.path.realpath(__file__))
TILTED = os.path.join(HERE, 'urdf', 'tilted_axis_arm.urdf')
ROBOTS = sorted(glob.glob(os.path.join(ROBOTS_DIR, '*.urdf')) + glob.glob(os.path.join(ROBOTS_DIR, 'fixtures', '*.urdf')))


def check_fk(model, candidate, *args, mistake='euler'):
    proc = subprocess.run(['rosrun', 'robot_ai', 'check_fk', '--model', model, '--candidate', candidate] + list(args),
                          capture_output=True, text=True, timeout=300, env=dict(os.environ, WRONG_FK_MISTAKE=mistake))
    return proc.returncode, proc.stdout.strip().splitlines(), proc.stderr


class TestCheckFk(unittest.TestCase):

    def assert_verdict(self, model, candidate, status, start, *args, mistake='euler'):
        code, lines, err = check_fk(model, candidate, *args, mistake=mistake)
        verdict = [l for l in lines if l.startswith(('PASS', 'FAIL'))]
        self.assertTrue(verdict, '%s %s: no verdict\n%s\n%s' % (candidate, model, '\n'.join(lines), err[-2000:]))
        self.assertTrue(verdict[-1].startswith(start), '%s %s:\n%s' % (candidate, model, '\n'.join(lines)))
        self.assertEqual(code, status, '\n'.join(lines))
        return lines

    def test_passes_the_references_on_every_robot(self):
        self.assertGreaterEqual(len(ROBOTS), 8)
        for model in ROBOTS + [TILTED]:
            for candidate in ('robot_state_publisher/robot_state_publisher', 'robot_ai/forward_kinematics'):
                lines = self.assert_verdict(model, candidate, 0, 'PASS', '--configurations', '8')
                single = os.path.basename(model) == 'one_link.urdf'  # nothing to publish, nothing to compare
                self.assertIn('single link with no joint' if single else '8 configurations compared',
                              '\n'.join(lines))

    def test_a_7_joint_arm_in_under_a_minute(self):
        t = time.time()
        lines = self.assert_verdict(os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf'), 'robot_ai/forward_kinematics', 0,
                                    'PASS')
        self.assertIn('50 configurations compared', '\n'.join(lines))
        self.assertLess(time.time() - t, 60.0)

    def test_fails_a_wrong_node_where_the_mistake_shows_and_names_the_link(self):
        lines = self.assert_verdict(TILTED, 'robot_ai/wrong_fk_euler.py', 1, 'FAIL: forearm', '--configurations', '10')
        text = '\n'.join(lines)
        self.assertIn('check joint elbow', lines[-1])
        self.assertTrue(lines[-2].startswith('(graded in '))
        self.assertIn('frames the URDF does not have (not graded): world', text)
        table = {l.split()[0]: l for l in lines if l.split() and l.split()[0] in ('shoulder', 'upper_arm', 'forearm',
                                                                                  'tool')}
        self.assertNotIn('wrong', table['upper_arm'])   # above the tilted joint, the node is right
        self.assertIn('<- wrong', table['forearm'])
        self.assertIn('<- wrong', table['tool'])

    def test_passes_the_same_wrong_node_where_every_axis_is_x_y_or_z(self):
        self.assert_verdict(os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf'), 'robot_ai/wrong_fk_euler.py', 0, 'PASS',
                            '--configurations', '10')

    def test_fails_a_node_that_ignores_rpy_or_publishes_nan(self):
        ur5 = os.path.join(ROBOTS_DIR, 'ur5.urdf')   # base_link_inertia's joint has rpy 0 0 pi
        lines = self.assert_verdict(ur5, 'robot_ai/wrong_fk_euler.py', 1, 'FAIL: ', '--configurations', '5',
                                    mistake='rpy')
        self.assertIn('rpy', lines[-1])
        self.assert_verdict(ur5, 'robot_ai/wrong_fk_euler.py', 1, 'FAIL: the candidate published a non-finite',
                            '--configurations', '5', mistake='nan')

    def test_clear_verdicts_for_broken_candidates(self):
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        self.assert_verdict(kuka, 'robot_ai/no_such_node', 1, 'FAIL: the candidate node exited')
        t = time.time()
        self.assert_verdict(kuka, 'robot_ai/silent_fk.py', 1, 'FAIL: the candidate published nothing',
                            '--timeout', '3')
        self.assertLess(time.time() - t, 30.0)
        code, _, err = check_fk('/no/such.urdf', 'robot_ai/forward_kinematics')
        self.assertEqual(code, 2)
        self.assertIn('cannot read the model', err)
        code, _, err = check_fk(kuka, 'forward_kinematics')
        self.assertEqual(code, 2)
        self.assertIn('PACKAGE/TYPE', err)


if __name__ == '__main__':
    rostest.rosrun('robot_ai', 'test_check_fk', TestCheckFk)
