#!/usr/bin/env python3
"""arm_sim with physics (~physics mujoco) in the ROS graph: a loose object's pose on /tf where the physics has it
and drawn in its frame; the gripper's action (ros_control's gripper_action_controller goal) closes on a cube and
says it stalled there, gripping with the effort asked for; the arm lifts the cube it grips; the gripper opens and
says it reached the goal; a goal that is not numbers is aborted, the node keeps serving."""
import time
import unittest

import actionlib
import numpy as np
import rospy
import rostest
import tf2_ros
from actionlib_msgs.msg import GoalStatus
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from visualization_msgs.msg import MarkerArray

from robot_ai.msg import GripperCommand, GripperCommandAction, GripperCommandGoal

CUBE = 'the_cube'         # the frame of the object named "the cube"
EDGE = 0.03


class TestArmPhysics(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        cls.tf = tf2_ros.Buffer()
        cls.listener = tf2_ros.TransformListener(cls.tf)
        cls.states = []
        cls.sub = rospy.Subscriber('/joint_states', JointState, lambda m: cls.states.append(m), queue_size=100)
        cls.gripper = actionlib.SimpleActionClient('/gripper_controller/gripper_cmd', GripperCommandAction)
        assert cls.gripper.wait_for_server(rospy.Duration(180)), 'no gripper action server'
        cls.command = rospy.Publisher('/joint_group_position_controller/command', Float64MultiArray, queue_size=10)

    def cube(self) -> np.ndarray:
        t = self.tf.lookup_transform('panda_link0', CUBE, rospy.Time(0), rospy.Duration(30)).transform.translation
        return np.array([t.x, t.y, t.z])

    def grip(self, position: float, effort: float):
        goal = GripperCommandGoal(command=GripperCommand(position=position, max_effort=effort))
        self.assertTrue(self.gripper.send_goal_and_wait(goal, rospy.Duration(120)) is not None)
        return self.gripper.get_state(), self.gripper.get_result()

    def test_a_cube_on_tf_gripped_lifted_and_let_go(self):
        markers = rospy.wait_for_message('/arm_sim/object_markers', MarkerArray, timeout=60)
        self.assertEqual([(m.header.frame_id, m.type, round(m.scale.x, 6), m.text) for m in markers.markers],
                         [(CUBE, markers.markers[0].CUBE, EDGE, ''),
                          (CUBE, markers.markers[0].TEXT_VIEW_FACING, 0.0, 'the cube')])
        rest = self.cube()      # on the table, whose top is at 0.225: its centre half an edge above, where it was put
        np.testing.assert_allclose(rest, [0.512, 0.0, 0.225 + EDGE / 2], atol=2e-3)

        state, result = self.grip(0.0, 10.0)           # closed, 10 N: the fingers stop on the cube
        self.assertEqual(state, GoalStatus.SUCCEEDED)
        self.assertTrue(result.stalled and not result.reached_goal, result)
        self.assertGreater(result.position, 0.005)          # short of closed: the cube is between the fingers
        self.assertAlmostEqual(abs(result.effort), 10.0, delta=0.5)

        deadline = time.monotonic() + 30
        while self.command.get_num_connections() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        names = list(self.states[-1].name)
        target = np.array(self.states[-1].position)
        target[names.index('panda_joint4')] += 0.3           # the forearm up: the hand rises by about 0.13 m
        target[names.index('panda_finger_joint1')] = 0.04    # the gripper's own: the arm's command no longer opens it
        self.command.publish(Float64MultiArray(data=target.tolist()))
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and self.cube()[2] < rest[2] + 0.1:
            time.sleep(0.2)
        self.assertGreater(self.cube()[2], rest[2] + 0.1)     # lifted with the hand
        time.sleep(1.0)
        self.assertGreater(self.cube()[2], rest[2] + 0.1)     # and held there

        state, result = self.grip(0.04, 0.0)           # open: reached, and the cube falls to the table
        self.assertEqual(state, GoalStatus.SUCCEEDED)
        self.assertTrue(result.reached_goal and not result.stalled, result)
        self.assertAlmostEqual(result.position, 0.04, delta=0.04 * 0.02)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and self.cube()[2] > rest[2] + 0.005:
            time.sleep(0.2)
        self.assertLess(self.cube()[2], rest[2] + 0.005)

        state, result = self.grip(float('nan'), 0.0)   # not a position: aborted, and the node goes on
        self.assertEqual(state, GoalStatus.ABORTED)
        self.assertIn('finite', self.gripper.get_goal_status_text())
        state, result = self.grip(0.04, 0.0)
        self.assertEqual(state, GoalStatus.SUCCEEDED)


if __name__ == '__main__':
    rospy.init_node('test_arm_physics')
    rostest.rosrun('robot_ai', 'arm_physics', TestArmPhysics)
