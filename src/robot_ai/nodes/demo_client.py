"""demo_client: the headless demo's summary. Reads the end effector's pose from tf at a few instants, runs
the course's random search through the cartpole_search service and its Q-learning agent through the
cartpole_q_learning service, prints a readable summary and a verdict.

ROS Parameters
    ~base_frame (str, ""), ~tip_frame (str, ""): the pose printed; empty: the robot's root link, and the link
        below the most driven joints (KinematicTree.end_effector), found from robot_description.
    ~samples (int, 3): instants of the pose, ~interval (float, 0.5) seconds apart.
    ~record_video (bool, true): ask the search for a video of the best policy.
    ~search_service (str, /cartpole_search/random_search)
    ~q_learning_service (str, /cartpole_q_learning/train), ~q_learners (int, 4): learners trained side by side.

Exits 0 when the frames moved, the search balanced the pole and the Q-learning agents learned, 1 otherwise.
"""
import math
import os
import sys
import time

import rospy
import tf2_ros

from robot_ai.nodes.params import bool_param, int_param, number_param, str_param
from robot_ai.nodes.robot_description import wait_for_tree
from robot_ai.srv import QLearning, RandomSearch


def wait_plot(path, timeout=10.0):
    """A response arrives before its plot: wait for the plot process to put the file in place."""
    deadline = time.time() + timeout
    while path and not os.path.isfile(path) and time.time() < deadline:
        time.sleep(0.1)
    return bool(path) and os.path.isfile(path)


def frames(base, tip):
    """The frames to show: as given, or found from robot_description (its root, and the link below the most
    driven joints) for any robot."""
    if base and tip:
        return base, tip
    tree, _ = wait_for_tree()
    if tree is None:  # shut down while waiting
        sys.exit(1)
    return base or tree.root, tip or tree.end_effector()


def main():
    rospy.init_node('demo_client')
    base, tip = frames(str_param('~base_frame', ''), str_param('~tip_frame', ''))
    samples = int_param('~samples', 3, 'a whole number of at least 2', lambda v: v >= 2)
    interval = number_param('~interval', 0.5, 'a positive number (s)', lambda v: v > 0)
    record_video = bool_param('~record_video', True)
    service = str_param('~search_service', '/cartpole_search/random_search')
    q_service = str_param('~q_learning_service', '/cartpole_q_learning/train')
    q_learners = int_param('~q_learners', 4, 'a whole number from 1 to 64', lambda v: 1 <= v <= 64)
    buf = tf2_ros.Buffer()
    tf2_ros.TransformListener(buf)
    ok = True
    lines = ['', '=' * 72, 'robot_ai demo', '=' * 72, 'forward_kinematics: %s -> %s from /tf' % (base, tip)]
    positions, first = [], None
    for i in range(samples):
        try:
            t = buf.lookup_transform(base, tip, rospy.Time(0), rospy.Duration(20.0 if i == 0 else 2.0))
        except (tf2_ros.LookupException, tf2_ros.ExtrapolationException, tf2_ros.ConnectivityException) as e:
            lines.append('  no transform: %s' % e)
            ok = False
            break
        p, q = t.transform.translation, t.transform.rotation
        positions.append((p.x, p.y, p.z))
        first = first or t.header.stamp
        lines.append('  t=%5.2f s  xyz = (%+.4f, %+.4f, %+.4f) m  quat xyzw = (%+.3f, %+.3f, %+.3f, %+.3f)' % (
            (t.header.stamp - first).to_sec(), p.x, p.y, p.z, q.x, q.y, q.z, q.w))
        rospy.sleep(interval)
    moved = len(positions) > 1 and max(math.dist(positions[0], p) for p in positions[1:]) > 1e-4
    lines.append('  the end effector %s' % ('moves' if moved else 'does NOT move'))
    ok = ok and moved

    lines.append('cartpole_search: the course experiment (100 candidates x 100 episodes, CartPole-v1, seed 0)')
    try:
        rospy.wait_for_service(service, 60)
        t0 = time.time()
        res = rospy.ServiceProxy(service, RandomSearch)(record_video=record_video)
        round_trip = time.time() - t0
    except (rospy.ROSException, rospy.ServiceException) as e:
        lines.append('  service failed: %s' % e)
        res, ok = None, False
    if res is not None:
        ok = ok and res.success and res.best_avg_length >= 195.0  # CartPole's own 'solved' threshold (v0)
        lines.append('  %s' % res.message)
        lines.append('  best weights       [%s]' % ', '.join('%+.4f' % w for w in res.best_weights))
        lines.append('  best average       %.2f steps' % res.best_avg_length)
        lines.append('  final average      %.2f steps' % res.final_avg_length)
        lines.append('  search time        %.3f s (round trip %.3f s)' % (res.elapsed, round_trip))
        plot_ok = wait_plot(res.plot_path)
        lines.append('  learning curve     %s' % (res.plot_path if plot_ok else 'MISSING'))
        lines.append('  video              %s' % (res.video_path or '(not recorded)'))
        ok = ok and plot_ok and (not record_video or os.path.isfile(res.video_path))

    lines.append('cartpole_q_learning: the course\'s Q-learning with RBF features (CartPole-v0, 500 episodes), '
                 '%d learner%s' % (q_learners, 's' if q_learners > 1 else ''))
    try:
        rospy.wait_for_service(q_service, 60)
        res = rospy.ServiceProxy(q_service, QLearning)(learners=q_learners, record_video=record_video)
    except (rospy.ROSException, rospy.ServiceException) as e:
        lines.append('  service failed: %s' % e)
        res, ok = None, False
    if res is not None:
        # learned: far above random actions (about 22) in every learner; the course's run reached 198.79
        ok = ok and res.success and len(res.last100_averages) == q_learners and min(res.last100_averages) > 150
        lines.append('  %s' % res.message.split('; ')[0])
        lines.append('  every learner      %s' % ', '.join('%.2f' % v for v in res.last100_averages))
        lines.append('  training time      %.1f s' % res.elapsed)
        plot_ok = wait_plot(res.plot_path)
        lines.append('  learning curves    %s' % (res.plot_path if plot_ok else 'MISSING'))
        lines.append('  video              %s' % (res.video_path or '(not recorded)'))
        lines.append('avg reward for last 100 episodes: %.2f' % res.mean_last100)
        ok = ok and plot_ok and (not record_video or os.path.isfile(res.video_path))
    lines.append('verdict: %s' % ('OK - frames move, the search balanced the pole, the Q-learning agents learned'
                                  if ok else 'FAILED'))
    lines.append('=' * 72)
    print('\n'.join(lines))
    sys.stdout.flush()
    sys.exit(0 if ok else 1)
