#!/usr/bin/env python3
"""A deliberately wrong FK node, in the course skeleton's style, for check_fk's tests (never installed).

It hangs every link directly under a 'world' frame the URDF does not have, as the course's skeleton does, and
rotates a revolute joint by the euler angles axis * q: right for an axis along x, y or z, wrong for any
other axis. The mistake is the environment's WRONG_FK_MISTAKE (check_fk passes its environment on): 'euler'
(that, the default), 'rpy' (ignores every joint origin's rpy, with correct rotations) or 'nan' (right, but
the last link's pose is NaN).
"""
import os

import numpy as np
import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped
from sensor_msgs.msg import JointState
from tf import transformations as tft

from robot_ai.kinematics import KinematicTree


def main():
    rospy.init_node('wrong_fk')
    mistake = os.environ.get('WRONG_FK_MISTAKE', 'euler')
    tree = KinematicTree.from_xml_string(rospy.get_param('robot_description'))
    broadcaster = tf2_ros.TransformBroadcaster()

    def joint_matrix(joint, q):
        origin = joint.matrix if mistake != 'rpy' else tft.translation_matrix(joint.xyz)
        if joint.type in ('revolute', 'continuous'):
            if mistake == 'euler':  # right for x, y, z only
                motion = tft.euler_matrix(*(np.asarray(joint.axis) * q))
            else:
                motion = tft.rotation_matrix(q, joint.axis)
        elif joint.type == 'prismatic':
            motion = tft.translation_matrix(np.asarray(joint.axis) * q)
        else:
            motion = np.identity(4)
        return origin.dot(motion)

    def on_joint_states(msg):
        q = dict(zip(msg.name, msg.position))
        q = tree.resolve_positions(q)
        poses = {tree.root: np.identity(4)}
        for name in tree.joint_order:
            j = tree.joints[name]
            if j.parent in poses:
                poses[j.child] = poses[j.parent].dot(joint_matrix(j, q.get(name, 0.0)))
        out = []
        for link, m in poses.items():
            t = TransformStamped()
            t.header.stamp = rospy.Time.now()
            t.header.frame_id, t.child_frame_id = 'world', link
            t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = m[:3, 3]
            (t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z,
             t.transform.rotation.w) = tft.quaternion_from_matrix(m)
            out.append(t)
        if mistake == 'nan':
            out[-1].transform.translation.x = float('nan')
        broadcaster.sendTransform(out)

    rospy.Subscriber('joint_states', JointState, on_joint_states, queue_size=1)
    rospy.spin()


if __name__ == '__main__':
    main()
