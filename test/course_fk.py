#!/usr/bin/env python
"""A forward-kinematics node shaped like the course's skeleton (CSMM.103x), for check_fk's tests (never installed).
Like the skeleton it starts `#!/usr/bin/env python` and reads the robot with `URDF.from_parameter_server()`.

It reads the URDF, walks from the root while each link has exactly one child (at a fork it logs an error and stops),
and on every joint_states publishes one tfMessage with PARENT -> link for every link it found, stamped
rospy.Time.now(), the transforms computed with tf.transformations. PARENT is the environment's COURSE_FK_PARENT
('world' by default; the course's skeleton says 'world_link'). COURSE_FK_MISTAKE picks what a student got wrong:
  none       right
  sleep      right, but its callback sleeps COURSE_FK_SLEEP seconds (0.1 by default: a slow student node)
  every_other  right, but it answers every other joint_states only (a node that drops messages)
  first      ignores the first moving joint's angle
  order      applies a joint's motion before its origin (rotation and translation in the wrong order)
  rpy_order  composes each origin's rpy in the wrong order (z, y, x about the moving axes of the wrong kind)
  raise      calls rospy.logerror, which does not exist: an AttributeError in every callback (rospy logs its
             traceback and the node publishes nothing)
  die        looks up a joint the robot does not have at start: a ValueError, and the node exits
  orphan     right, and it starts a child that ignores SIGINT (sleep 600, marked by COURSE_FK_MARK)
  chatty     right, and it writes 20 KB to stderr on every joint_states (a pipe nobody reads fills in 4 calls)
  kuka       publishes the KUKA LWR's link names whatever the URDF (a node written for another robot)
  flood      right, and it also publishes 200 ever-new frame names a message, and once a 100 KB frame name
  abandon    starts a child that keeps its stdout and stderr open (sleep 600), then exits with status 3
  stubborn   right, but it ignores SIGINT itself, starts a child that ignores SIGINT and a grandchild that
             double-forks into a session of its own (all marked by COURSE_FK_MARK)
  escape     right, and a grandchild double-forked into a session of its own (marked) outlives it
  bigline    right, and it writes 1 GiB to stdout without a newline
"""
import os
import subprocess
import sys
import time

import numpy as np
import rospy
from geometry_msgs.msg import TransformStamped
from sensor_msgs.msg import JointState
from tf import transformations as tft
from tf2_msgs.msg import TFMessage
from urdf_parser_py.urdf import URDF


def chain(robot):
    """The links from the root's child down while each link has exactly one child, with their joints."""
    children = {}
    for j in robot.joints:
        children.setdefault(j.parent, []).append(j)
    out, link = [], robot.get_root()
    while True:
        below = children.get(link, [])
        if len(below) != 1:
            if len(below) > 1:
                rospy.logerr('%s has %d children: this node handles chains only, stopping there', link, len(below))
            return out
        out.append(below[0])
        link = below[0].child


def main():
    rospy.init_node('course_fk')
    parent = os.environ.get('COURSE_FK_PARENT', 'world')
    mistake = os.environ.get('COURSE_FK_MISTAKE', 'none')
    robot = URDF.from_parameter_server()      # the course's skeleton, as it is
    joints = chain(robot)
    if mistake == 'die':
        [j.name for j in joints].index('tool_mount')
    if mistake == 'abandon':
        subprocess.Popen(['sh', '-c', 'sleep 600; : ' + os.environ.get('COURSE_FK_MARK', '')])
        print('leaving my child behind', flush=True)
        os._exit(3)
    mark = os.environ.get('COURSE_FK_MARK', '')
    if mistake in ('orphan', 'stubborn'):
        subprocess.Popen(['sh', '-c', 'trap "" INT; sleep 600; : ' + mark])
    if mistake in ('stubborn', 'escape'):
        # setsid's child forks the sleeper and exits: the sleeper is an orphan in a session of its own
        subprocess.Popen(['setsid', 'sh', '-c', f'(trap "" INT HUP TERM; sleep 601; : {mark}_escaped) & exit 0'],
                         stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    if mistake == 'stubborn':
        import signal
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    if mistake == 'bigline':
        import threading

        def write_a_gigabyte():
            chunk = b'y' * (1 << 20)
            for _ in range(1024):
                sys.stdout.buffer.write(chunk)
            sys.stdout.buffer.flush()
        threading.Thread(target=write_a_gigabyte, daemon=True).start()
    moving = [j.name for j in joints if j.type != 'fixed']
    pub = rospy.Publisher('/tf', TFMessage, queue_size=10)
    sent = []      # the flood's messages so far
    pause = float(os.environ.get('COURSE_FK_SLEEP', '0.1'))
    calls = [0]

    def origin(j):
        xyz = j.origin.xyz if j.origin is not None and j.origin.xyz is not None else [0, 0, 0]
        rpy = j.origin.rpy if j.origin is not None and j.origin.rpy is not None else [0, 0, 0]
        axes = 'rzyx' if mistake == 'rpy_order' else 'sxyz'
        return tft.translation_matrix(xyz).dot(tft.euler_matrix(rpy[0], rpy[1], rpy[2], axes))

    def motion(j, q):
        axis = j.axis if j.axis is not None else [1, 0, 0]
        if j.type in ('revolute', 'continuous'):
            return tft.rotation_matrix(q, axis)
        if j.type == 'prismatic':
            return tft.translation_matrix(np.asarray(axis) * q)
        return np.identity(4)

    def callback(msg):
        if mistake == 'sleep':
            time.sleep(pause)
        calls[0] += 1
        if mistake == 'every_other' and calls[0] % 2:
            return
        if mistake == 'raise':
            rospy.logerror('computing the transforms')
        if mistake == 'chatty':
            sys.stderr.write('debug: ' + 'x' * 20000 + '\n')
            sys.stderr.flush()
        q = dict(zip(msg.name, msg.position))
        pose, out = np.identity(4), TFMessage()
        for j in joints:
            value = 0.0 if mistake == 'first' and moving and j.name == moving[0] else q.get(j.name, 0.0)
            step = motion(j, value).dot(origin(j)) if mistake == 'order' else origin(j).dot(motion(j, value))
            pose = pose.dot(step)
            t = TransformStamped()
            t.header.stamp = rospy.Time.now()
            t.header.frame_id = parent
            t.child_frame_id = 'lwr_arm_%d_link' % len(out.transforms) if mistake == 'kuka' else j.child
            t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = pose[:3, 3]
            (t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z,
             t.transform.rotation.w) = tft.quaternion_from_matrix(pose)
            out.transforms.append(t)
        if mistake == 'flood':
            for k in range(200):
                t = TransformStamped()
                t.header.stamp, t.header.frame_id = rospy.Time.now(), parent
                t.child_frame_id = 'junk_%d_%d' % (len(sent), k) if k or sent else 'x' * 100000
                t.transform.rotation.w = 1.0
                out.transforms.append(t)
            sent.append(1)
        pub.publish(out)

    rospy.Subscriber('joint_states', JointState, callback)
    rospy.spin()


if __name__ == '__main__':
    main()
