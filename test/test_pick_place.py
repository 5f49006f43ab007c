#!/usr/bin/env python3
"""pick_place in the ROS graph (pick.launch, no rviz): clicks on /clicked_point as rviz's Publish Point sends them.
A click on nothing and a place off the table are refused with one line on ~result; a cube clicked, then a place on
the table: ~result says placed, and the cube's frame on /tf (arm_sim's physics) rests there; the second cube, from
where the first pick left the arm (a planned way to the ready configuration first), placed too; a pick cancelled on
its way (~cancel) is said not placed."""
import time
import unittest

import numpy as np
import rospy
import rostest
import tf2_ros
from geometry_msgs.msg import PointStamped
from std_msgs.msg import String
from std_srvs.srv import Trigger

ROOT = 'base_link'


class TestPickPlace(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        cls.tf = tf2_ros.Buffer()
        cls.listener = tf2_ros.TransformListener(cls.tf)
        cls.results = []
        cls.sub = rospy.Subscriber('/pick_place/result', String, lambda m: cls.results.append(m.data), queue_size=10)
        cls.clicks = rospy.Publisher('/clicked_point', PointStamped, queue_size=10)
        deadline = time.monotonic() + 240           # pick_place ready: it subscribes to the clicks
        while cls.clicks.get_num_connections() == 0 and time.monotonic() < deadline:
            time.sleep(0.2)
        assert cls.clicks.get_num_connections(), 'pick_place never subscribed to /clicked_point'

    def click(self, x, y, z) -> int:
        """Publish a click as rviz's Publish Point does; the number of results before it (result's count: an answer
        can come before the test reads the count after the click, on a loaded machine)."""
        count = len(self.results)
        msg = PointStamped()
        msg.header.frame_id, msg.header.stamp = ROOT, rospy.Time.now()
        msg.point.x, msg.point.y, msg.point.z = x, y, z
        self.clicks.publish(msg)
        return count

    def result(self, count: int, timeout: float = 180.0) -> str:
        """The first result after the count-th (count: click's)."""
        deadline = time.monotonic() + timeout
        while len(self.results) == count and time.monotonic() < deadline and not rospy.is_shutdown():
            time.sleep(0.05)
        self.assertGreater(len(self.results), count, 'no result on /pick_place/result')
        return self.results[count]

    def position(self, frame: str) -> np.ndarray:
        t = self.tf.lookup_transform(ROOT, frame, rospy.Time(0), rospy.Duration(60)).transform.translation
        return np.array([t.x, t.y, t.z])

    def test_clicked_cubes_placed_where_clicked(self):
        cube = self.position('cube')
        top = cube[2] - 0.02                              # the table's top: under the 4 cm cube's middle
        count = self.click(cube[0], cube[1] + 0.3, top)   # nothing there
        self.assertRegex(self.result(count, 30), r'^not placed: no object within 0\.08 m')
        self.click(*(cube + [0, 0, 0.02]))                # the cube's top, as rviz picks a point on what it draws
        count = self.click(cube[0], cube[1], top + 0.2)   # in the air: not a place
        self.assertRegex(self.result(count, 30), r'^not placed: the place .* click on the table')
        for name, place in (('cube', (0.45, 0.1)), ('cube_2', (0.5, -0.15))):
            start = self.position(name)
            self.click(*(start + [0, 0, 0.02]))
            said = self.result(self.click(place[0], place[1], top))
            self.assertTrue(said.startswith(f'placed {name} at'), said)
            time.sleep(0.5)
            np.testing.assert_allclose(self.position(name), [place[0], place[1], top + 0.02], atol=0.015)
        # a pick cancelled on its way: said, the arm holds, and the next click chooses again
        rospy.wait_for_service('/pick_place/cancel', timeout=30)
        cancel = rospy.ServiceProxy('/pick_place/cancel', Trigger)
        self.assertFalse(cancel().success)                # nothing under way
        start = self.position('cube')
        self.click(*(start + [0, 0, 0.02]))
        count = self.click(0.65, 0.15, top)
        deadline = time.monotonic() + 60
        answer = cancel()
        while not answer.success and time.monotonic() < deadline:     # as soon as the pick is under way
            time.sleep(0.05)
            answer = cancel()
        self.assertTrue(answer.success, answer.message)
        self.assertEqual(self.result(count, 30), 'not placed: the pick of cube was cancelled (the arm holds)')


if __name__ == '__main__':
    rospy.init_node('test_pick_place_clicks')
    rostest.rosrun('robot_ai', 'pick_place_clicks', TestPickPlace)
