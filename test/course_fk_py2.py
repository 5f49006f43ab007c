#!/usr/bin/env python
# A student's forward-kinematics node in the course's style, still in Python 2 (a print statement), as many
# submissions of the CSMM.103x project were: ROS Noetic's Python 3 cannot parse it. For check_fk's tests.
import numpy
import rospy
from geometry_msgs.msg import TransformStamped
from sensor_msgs.msg import JointState
import tf
import tf.msg
from urdf_parser_py.urdf import URDF


def convert_to_message(T, child, parent):
    t = TransformStamped()
    t.header.frame_id = parent
    t.header.stamp = rospy.Time.now()
    t.child_frame_id = child
    translation = tf.transformations.translation_from_matrix(T)
    rotation = tf.transformations.quaternion_from_matrix(T)
    t.transform.translation.x = translation[0]
    t.transform.translation.y = translation[1]
    t.transform.translation.z = translation[2]
    t.transform.rotation.x = rotation[0]
    t.transform.rotation.y = rotation[1]
    t.transform.rotation.z = rotation[2]
    t.transform.rotation.w = rotation[3]
    return t


class ForwardKinematics(object):

    def __init__(self):
        rospy.Subscriber("joint_states", JointState, self.callback)
        self.pub_tf = rospy.Publisher("/tf", tf.msg.tfMessage, queue_size=1)
        self.robot = URDF.from_parameter_server()

    def callback(self, joint_values):
        root = self.robot.get_root()
        link_names = []
        joints = []
        link = root
        while True:
            if link not in self.robot.child_map:
                break
            (joint_name, next_link) = self.robot.child_map[link][0]
            joints.append(self.robot.joint_map[joint_name])
            link_names.append(next_link)
            link = next_link
        all_transforms = tf.msg.tfMessage()
        T = tf.transformations.identity_matrix()
        for i, joint in enumerate(joints):
            T = numpy.dot(T, tf.transformations.translation_matrix(joint.origin.xyz))
            all_transforms.transforms.append(convert_to_message(T, link_names[i], "world_link"))
        self.pub_tf.publish(all_transforms)


if __name__ == '__main__':
    rospy.init_node('fwk', anonymous=True)
    print "forward kinematics node started"
    fwk = ForwardKinematics()
    rospy.spin()
