"""demo_client: the headless demo's summary. Reads the end effector's pose from tf at a few instants, runs
the course's random search through the cartpole_search service, prints a readable summary and a verdict.

ROS Parameters
    ~base_frame (str, base_link), ~tip_frame (str, tool0): the pose printed.
    ~samples (int, 3): instants of the pose, ~interval (float, 0.5) seconds apart.
    ~record_video (bool, true): ask the search for a video of the best policy.
    ~search_service (str, /cartpole_search/random_search)

Exits 0 when the frames moved and the search succeeded, 1 otherwise.
"""
import math
import os
import sys
import time

import rospy
import tf2_ros

from robot_ai.srv import RandomSearch


def main():
    rospy.init_node('demo_client')
    base = rospy.get_param('~base_frame', 'base_link')
    tip = rospy.get_param('~tip_frame', 'tool0')
    samples = int(rospy.get_param('~samples', 3))
    interval = float(rospy.get_param('~interval', 0.5))
    record_video = bool(rospy.get_param('~record_video', True))
    service = rospy.get_param('~search_service', '/cartpole_search/random_search')
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
        deadline = time.time() + 10
        while res.plot_path and not os.path.isfile(res.plot_path) and time.time() < deadline:
            time.sleep(0.1)
        lines.append('  learning curve     %s' % (res.plot_path if os.path.isfile(res.plot_path) else 'MISSING'))
        lines.append('  video              %s' % (res.video_path or '(not recorded)'))
        ok = ok and os.path.isfile(res.plot_path) and (not record_video or os.path.isfile(res.video_path))
    lines.append('verdict: %s' % ('OK - frames move and the search balanced the pole' if ok else 'FAILED'))
    lines.append('=' * 72)
    print('\n'.join(lines))
    sys.stdout.flush()
    sys.exit(0 if ok else 1)
