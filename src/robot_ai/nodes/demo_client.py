"""demo_client: the headless demo's summary. Reads the end effector's pose from tf at a few instants, runs
the course's random search through the cartpole_search service and its Q-learning agent through the
cartpole_q_learning service, then drives the cart-pole robot with the agent's saved policy (through
cartpole_controller's ~load_policy), pushes its pole, and prints a readable summary and a verdict.

ROS Parameters
    ~base_frame (str, ""), ~tip_frame (str, ""): the pose printed; empty: the robot's root link (on a floating
        base, the floating joint's child), and the arm's end (KinematicTree.end_effector), from robot_description.
    ~samples (int, 3): instants of the pose, ~interval (float, 0.5) seconds apart.
    ~record_video (bool, true): ask the search for a video of the best policy.
    ~search_service (str, /cartpole_search/random_search)
    ~q_learning_service (str, /cartpole_q_learning/train), ~q_learners (int, 4): learners trained side by side.
    ~cartpole_ns (str, /cartpole): where cartpole_sim and cartpole_controller run; "" = no closed loop.
    ~balance_steps (int, 1000): sim steps watched before the push (20 s of simulated time).
    ~push (float, 0.2): the push, rad/s added to the pole's angular velocity. The course's Q-learning agent
        recovers from 0.2 in 200 of 200 trials in gymnasium's physics, from +0.3 in about half.
    ~reach_ns (str, /reach): where arm_sim and reach_controller run (reach.launch); "" = no reach.
    ~reach_goals (int, 3): seeded goals (seed ~reach_seed, 0) the arm reaches through ROS, each from home.

Exits 0 when the frames moved, the search balanced the pole, the Q-learning agents learned, the saved policy
kept the cart-pole's pole up through the push, ARS learned to reach 95 % of fresh goals and the arm reached every
seeded goal through ROS; 1 otherwise.
"""
import math
import os
import queue
import sys
import time

import rospkg
import rospy
import tf2_ros
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from robot_ai.msg import CartPoleEpisode
from robot_ai.nodes.params import bool_param, init_node, int_param, number_param, quiet_on_shutdown, str_param
from robot_ai.nodes.robot_description import wait_for_tree
from robot_ai.srv import LoadPolicy, PushPole, QLearning, RandomSearch
from robot_ai.text import counted, percent

UPRIGHT = 0.02           # rad: the pole counts as back upright within this of vertical
STALL = 20.0             # seconds without a cart-pole state after which the closed loop counts as stopped


def wait_plot(path: str, timeout: float = 10.0) -> bool:
    """A response arrives before its plot: wait for the plot process to put the file in place."""
    deadline = time.time() + timeout
    while path and not os.path.isfile(path) and time.time() < deadline:
        time.sleep(0.1)
    return bool(path) and os.path.isfile(path)


def last_words(node: str) -> str:
    """The last FATAL or ERROR line `node` logged in this launch (rosout.log of the run's log folder), or ''."""
    try:
        folder = os.path.join(rospkg.get_log_dir(), str(rospy.get_param('/run_id')))
        with open(os.path.join(folder, 'rosout.log'), errors='replace') as f:
            lines = f.readlines()[-20000:]
    except (OSError, KeyError, rospy.ROSException):
        return ''
    for line in reversed(lines):
        words = line.split(None, 4)
        if len(words) == 5 and words[1] in ('FATAL', 'ERROR') and words[2] == node:
            text = words[4].split('] ', 2)[-1].strip()     # after [file:line(function)] [topics: ...]
            return text[:300]
    return ''


def wait_for_node_service(service: str, timeout: float) -> None:
    """rospy.wait_for_service, ended early when the node that serves it has died with a fatal error; the
    ROSException then says which node, and why (its last words), not only that time ran out."""
    node = '/' + service.strip('/').rsplit('/', 1)[0]
    deadline = time.time() + timeout
    while True:
        if rospy.core.is_shutdown_requested():   # a Ctrl-C: the demo ends here, quietly (it waited its 60 s, and
            raise SystemExit(0)                  # roslaunch escalated to SIGKILL after 17 s)
        try:
            rospy.wait_for_service(service, min(2.0, max(0.1, deadline - time.time())))
            return
        except rospy.ROSException:
            if rospy.core.is_shutdown_requested():
                raise SystemExit(0)
            words = last_words(node)
            if words or time.time() >= deadline:
                raise rospy.ROSException(f'{node} is not serving {service}'
                                         + (f': it ended with "{words}"' if words else
                                            f' after {timeout:g} s (is it running? rosnode info {node})'))


def artifact_failures(what: str, plot_ok: bool, record_video: bool, video_path: str) -> list[str]:
    """The missing files of a search or a training, as verdict items."""
    failed = [] if plot_ok else [f'the {what}\'s learning-curve plot is missing']
    if record_video and not os.path.isfile(video_path):
        failed.append(f'the {what}\'s video is missing')
    return failed


def frames(base: str, tip: str) -> tuple[str, str]:
    """The frames to show: as given, or found from robot_description for any robot: the arm's end
    (KinematicTree.end_effector) in the root's frame, or in the floating base's (nothing publishes the root's)."""
    if base and tip:
        return base, tip
    tree, _ = wait_for_tree()
    if tree is None:  # shut down while waiting
        sys.exit(1)
    tip = tip or tree.end_effector()
    return base or tree.frame_above(tip), tip


def watch(states: queue.Queue, episodes: list, steps: int, stall: float = STALL) -> tuple[list, list, float]:
    """The next `steps` cart-pole states (x, theta), the episodes that ended meanwhile, and the wall seconds it
    took. It waits as long as states keep coming (the sim waits for its controller, so a busy machine makes it
    slower, not wrong); it gives up after `stall` seconds without one."""
    seen, first = [], len(episodes)
    t0 = last = time.time()
    while len(seen) < steps and time.time() - last < stall and not rospy.is_shutdown():
        try:
            seen.append(states.get(timeout=0.5))
            last = time.time()
        except queue.Empty:
            pass
    return seen, episodes[first:], time.time() - t0


def closed_loop(ns: str, policy_path: str, balance_steps: int, push: float) -> tuple[list[str], list[str]]:
    """Drive the cart-pole with the policy file, watch it, push it: (summary lines, the checks that failed)."""
    lines = []
    try:
        for name in ('cartpole_controller/load_policy', 'cartpole_sim/reset', 'cartpole_sim/push'):
            wait_for_node_service(f'{ns}/{name}', 30)
        loaded = rospy.ServiceProxy(f'{ns}/cartpole_controller/load_policy', LoadPolicy)(path=policy_path)
    except (rospy.ROSException, rospy.ServiceException) as e:
        return [f'  cartpole_sim and cartpole_controller not reached: {e}'], [f'cart-pole nodes not reached: {e}']
    if not loaded.success:
        return [f'  the controller refused the policy: {loaded.message}'], ['the controller refused the policy']
    tau = 0.02
    rtf = rospy.get_param(f'{ns}/cartpole_sim/real_time_factor', 1.0)
    states, episodes, arrived = queue.Queue(), [], [0]

    def on_state(m: JointState) -> None:
        arrived[0] += 1
        states.put((m.position[0], m.position[1]))

    def on_episode(m: CartPoleEpisode) -> None:
        # an episode longer than the states that came since the reset ended before it (its message came late,
        # under load): not the policy's
        if m.steps <= arrived[0] + 5:
            episodes.append(m)

    sub = rospy.Subscriber(f'{ns}/joint_states', JointState, on_state, queue_size=10000)
    ep_sub = rospy.Subscriber(f'{ns}/cartpole_sim/episodes', CartPoleEpisode, on_episode, queue_size=100)
    try:
        deadline = time.time() + 10
        while (sub.get_num_connections() < 1 or ep_sub.get_num_connections() < 1) and time.time() < deadline:
            time.sleep(0.05)                                  # the subscriptions connect
        arrived[0] = -10 ** 9                                 # until the reset: every episode is an old one
        rospy.ServiceProxy(f'{ns}/cartpole_sim/reset', Trigger)()
        while not states.empty():
            states.get()
        arrived[0] = 0
        seen, ended, seconds = watch(states, episodes, balance_steps)
        fell = [e for e in ended if e.reason == 'pole fell']
        up = (fell[0].steps if fell else len(seen)) * tau
        drift = sum(e.reason == 'cart left the rail' for e in ended)
        missed = sum(e.missed_steps for e in ended)
        lines.append(f'  {loaded.message}')
        lines.append(f'cartpole: the pole stayed up {up:.1f} s of {len(seen) * tau:.1f} s of simulated time '
                     f'(real_time_factor {rtf:g}: {len(seen) / max(1e-9, seconds):.0f} states/s measured'
                     + (f', {counted(missed, "step")} without the controller\'s answer' if missed else '') + ')'
                     + (f'; the cart left the rail {drift} time(s) and the sim reset (the policy\'s drift)'
                        if drift else ''))
        failed = []
        if fell:
            failed.append(f'the pole fell after {counted(fell[0].steps, "step")}')
        if len(seen) < balance_steps:
            failed.append(f'{len(seen)} of {balance_steps} states arrived (none for {STALL:g} s)')
        rospy.ServiceProxy(f'{ns}/cartpole_sim/push', PushPole)(angular_velocity=push)
        after, ended, _ = watch(states, episodes, 250)
        fell_after = [e for e in ended if e.reason == 'pole fell']
        peak = max((abs(theta) for _, theta in after), default=float('nan'))
        back = next((i for i, (_, theta) in enumerate(after) if i > 5 and abs(theta) < UPRIGHT), None)
        recovered = not fell_after and back is not None and len(after) >= 250
        lines.append(f'  push of {push:+g} rad/s: the pole leaned to {math.degrees(peak):.1f} degrees, '
                     + (f'back within {math.degrees(UPRIGHT):.1f} degrees after {back * tau:.2f} s: recovered'
                        if recovered else 'and fell: NOT recovered' if fell_after else 'and did not come back'))
        if not recovered:
            failed.append(f'the push of {push:+g} rad/s: peak {math.degrees(peak):.1f} degrees, '
                          + ('the pole fell' if fell_after else f'{len(after)} states, never back upright'))
        return lines, failed
    finally:
        sub.unregister()
        ep_sub.unregister()


def wait_home(ns: str, joints: list[str], home: list[float], timeout: float = 30.0) -> bool:
    """Whether the arm's joints came within a milliradian of home within timeout seconds."""
    deadline = time.time() + timeout
    while time.time() < deadline and not rospy.is_shutdown():
        msg = rospy.wait_for_message(f'{ns}/joint_states', JointState, timeout)
        position = dict(zip(msg.name, msg.position))
        if all(abs(position.get(n, 1e9) - h) < 1e-3 for n, h in zip(joints, home)):
            return True
        rospy.sleep(0.1)
    return False


def seeded_goal_configurations(setup, count: int, seed: int, margin: float):
    """(count, n): count configurations drawn within the limits from seed; with a body, each one in contact or
    within margin of a contact drawn again from the same generator (a goal the arm's body cannot take is no goal to
    ask of it: the Panda's stand-in body made one inside its own base). Without a body: the same draws as ever."""
    import numpy as np
    arm, rng = setup.arm, np.random.default_rng(seed)
    q = rng.uniform(arm.lower, arm.upper, (count, arm.n))
    if setup.body is None:
        return q
    for i in range(count):
        for _ in range(1000):
            if not setup.body.in_collision(q[i:i + 1], margin)[0]:
                break
            q[i] = rng.uniform(arm.lower, arm.upper)
    return q


def reach(ns: str, count: int, seed: int) -> tuple[list[str], list[str]]:
    """The reach through ROS: ARS's figures from the controller, then count seeded goals, each from home: (summary
    lines, the checks that failed)."""
    from geometry_msgs.msg import PointStamped
    from std_msgs.msg import Float64
    from robot_ai.reach import ReachSetup
    controller = f'{ns}/reach_controller'
    try:
        wait_for_node_service(f'{controller}/home', 300)       # it learns with ARS before it serves
    except rospy.ROSException as e:
        return [f'  reach_controller not reached: {e}'], [f'reach_controller not reached: {e}']
    info = rospy.get_param(f'{controller}/policy_info', '?')
    rate = float(rospy.get_param(f'{controller}/success_rate', -1.0))
    lines = [f'  {info}']
    failed = [] if rate >= 0.95 else [f'ARS reached {percent(rate)} of fresh goals (95 % wanted)']
    setup = ReachSetup(urdf=rospy.get_param(f'{ns}/robot_description'),
                       tip=rospy.get_param(f'{controller}/tip', '') or None,
                       obstacles=rospy.get_param(f'{controller}/obstacles', '') or None,
                       collision=bool(rospy.get_param(f'{controller}/collision', False)),
                       home=rospy.get_param(f'{controller}/home_position', None) or None)
    arm, threshold = setup.arm, setup.task.distance_threshold
    goals = arm.tip_positions(seeded_goal_configurations(setup, count, seed,
                                                         float(rospy.get_param(f'{controller}/collision_margin', 0.0))))
    distances = queue.Queue()
    sub = rospy.Subscriber(f'{controller}/distance', Float64, lambda m: distances.put(m.data), queue_size=1000)
    pub = rospy.Publisher(f'{controller}/goal', PointStamped, queue_size=1, latch=True)
    home = rospy.ServiceProxy(f'{controller}/home', Trigger)
    try:
        for i, goal in enumerate(goals, 1):
            home()
            if not wait_home(ns, arm.joints, setup.home.tolist()):
                failed.append(f'the arm did not come home before goal {i}')
            while not distances.empty():
                distances.get()
            msg = PointStamped()
            msg.header.frame_id, msg.header.stamp = arm.base, rospy.Time.now()
            msg.point.x, msg.point.y, msg.point.z = (float(v) for v in goal)
            pub.publish(msg)
            t0, reached, closest = time.time(), None, float('inf')
            while time.time() - t0 < 30 and reached is None and not rospy.is_shutdown():
                try:
                    d = distances.get(timeout=1.0)
                except queue.Empty:
                    continue
                closest = min(closest, d)
                if d < threshold:
                    reached = time.time() - t0
            where = f'goal {i} ({goal[0]:+.3f}, {goal[1]:+.3f}, {goal[2]:+.3f}) m in {arm.base}'
            if reached is not None:
                lines.append(f'  {where}: reached in {reached:.2f} s ({closest:.3f} m)')
            else:
                lines.append(f'  {where}: NOT reached, closest {closest:.3f} m')
                failed.append(f'{where} not reached (closest {closest:.3f} m)')
        home()
    finally:
        sub.unregister()
        pub.unregister()
    return lines, failed


def lookup(buf: tf2_ros.Buffer, base: str, tip: str, timeout: float):
    """buf.lookup_transform(base, tip) of the latest, waited for up to timeout seconds but not past a shutdown: tf2's
    own wait polls with wall-clock sleeps that no Ctrl-C ends (the node then ignored SIGINT and SIGTERM until its
    timeout), so it waits here in short slices and raises ROSInterruptException on shutdown."""
    deadline = time.monotonic() + timeout
    while not buf.can_transform(base, tip, rospy.Time(0), rospy.Duration(0.05)):
        if rospy.is_shutdown() or rospy.core.is_shutdown_requested():
            raise rospy.ROSInterruptException('shut down while waiting for a transform')
        if time.monotonic() >= deadline:
            break
    return buf.lookup_transform(base, tip, rospy.Time(0))


@quiet_on_shutdown
def main():
    init_node('demo_client')
    base, tip = frames(str_param('~base_frame', ''), str_param('~tip_frame', ''))
    samples = int_param('~samples', 3, 'a whole number of at least 2', lambda v: v >= 2)
    interval = number_param('~interval', 0.5, 'a positive number (s)', lambda v: v > 0)
    record_video = bool_param('~record_video', True)
    service = str_param('~search_service', '/cartpole_search/random_search')
    q_service = str_param('~q_learning_service', '/cartpole_q_learning/train')
    q_learners = int_param('~q_learners', 4, 'a whole number from 1 to 64', lambda v: 1 <= v <= 64)
    cartpole_ns = str_param('~cartpole_ns', '/cartpole')
    balance_steps = int_param('~balance_steps', 1000)
    push = number_param('~push', 0.2, 'a number of rad/s', lambda v: True)
    reach_ns = str_param('~reach_ns', '/reach')
    reach_goals = int_param('~reach_goals', 3, 'a whole number from 1 to 100', lambda v: 1 <= v <= 100)
    reach_seed = int_param('~reach_seed', 0, 'a whole number', lambda v: True)
    buf = tf2_ros.Buffer()
    tf2_ros.TransformListener(buf)
    failed = []                           # the checks that failed, with their figures
    lines = ['', '=' * 72, 'robot_ai demo', '=' * 72, f'forward_kinematics: {base} -> {tip} from /tf']
    positions, first = [], None
    for i in range(samples):
        try:
            t = lookup(buf, base, tip, 20.0 if i == 0 else 2.0)
        except (tf2_ros.LookupException, tf2_ros.ExtrapolationException, tf2_ros.ConnectivityException) as e:
            lines.append(f'  no transform: {e}')
            failed.append(f'no transform {base} -> {tip} on /tf')
            break
        p, q = t.transform.translation, t.transform.rotation
        positions.append((p.x, p.y, p.z))
        first = first or t.header.stamp
        lines.append(f'  t={(t.header.stamp - first).to_sec():5.2f} s  xyz = ({p.x:+.4f}, {p.y:+.4f}, {p.z:+.4f}) m  '
                     f'quat xyzw = ({q.x:+.3f}, {q.y:+.3f}, {q.z:+.3f}, {q.w:+.3f})')
        rospy.sleep(interval)
    moved = len(positions) > 1 and max(math.dist(positions[0], p) for p in positions[1:]) > 1e-4
    lines.append(f'  the end effector {"moves" if moved else "does NOT move"}')
    if positions and not moved:
        failed.append(f'the end effector {tip} did not move')

    lines.append('cartpole_search: the course experiment (100 candidates x 100 episodes, CartPole-v1, seed 0)')
    search_policy = ''
    try:
        wait_for_node_service(service, 60)
        t0 = time.time()
        res = rospy.ServiceProxy(service, RandomSearch)(record_video=record_video)
        round_trip = time.time() - t0
    except (rospy.ROSException, rospy.ServiceException) as e:
        lines.append(f'  service failed: {e}')
        res = None
        failed.append(f'the search service failed: {e}')
    if res is not None:
        if not res.success:
            failed.append(f'the search failed: {res.message}')
        elif res.best_avg_length < 195.0:  # CartPole's own 'solved' threshold (v0)
            failed.append(f'the search\'s best average {res.best_avg_length:.2f} is below 195')
        search_policy = res.policy_path
        lines.append(f'  {res.message}')
        lines.append(f'  best weights       [{", ".join(f"{w:+.4f}" for w in res.best_weights)}]')
        lines.append(f'  best average       {res.best_avg_length:.2f} steps')
        lines.append(f'  final average      {res.final_avg_length:.2f} steps')
        lines.append(f'  search time        {res.elapsed:.3f} s (round trip {round_trip:.3f} s)')
        plot_ok = wait_plot(res.plot_path)
        lines.append(f'  learning curve     {res.plot_path if plot_ok else "MISSING"}')
        lines.append(f'  policy file        {res.policy_path or "(not written)"}')
        lines.append(f'  video              {res.video_path or "(not recorded)"}')
        failed += artifact_failures('search', plot_ok, record_video, res.video_path)

    lines.append('cartpole_q_learning: the course\'s Q-learning with RBF features (CartPole-v0, 500 episodes), '
                 f'{q_learners} learner{"s" if q_learners > 1 else ""}')
    q_policy = ''
    try:
        wait_for_node_service(q_service, 60)
        res = rospy.ServiceProxy(q_service, QLearning)(learners=q_learners, record_video=record_video)
    except (rospy.ROSException, rospy.ServiceException) as e:
        lines.append(f'  service failed: {e}')
        res = None
        failed.append(f'the Q-learning service failed: {e}')
    if res is not None:
        # learned: far above random actions (about 22) in every learner; the course's run reached 198.79
        if not res.success:
            failed.append(f'the Q-learning training failed: {res.message}')
        elif len(res.last100_averages) != q_learners or min(res.last100_averages) <= 150:
            failed.append(f'Q-learning: {len(res.last100_averages)} of {q_learners} learners finished, last-100 '
                          f'averages {", ".join(f"{v:.2f}" for v in res.last100_averages)} (each must be above 150)')
        q_policy = res.policy_path
        lines.append(f'  {res.message.split("; ")[0]}')
        lines.append(f'  every learner      {", ".join(f"{v:.2f}" for v in res.last100_averages)}')
        seed = res.learner_seeds[res.best_learner]
        lines.append(f'  best learner       {res.best_learner} (seed {seed}): greedy average '
                     f'{res.best_greedy_average:.1f} over 100 episodes')
        lines.append(f'  training time      {res.elapsed:.1f} s')
        plot_ok = wait_plot(res.plot_path)
        lines.append(f'  learning curves    {res.plot_path if plot_ok else "MISSING"}')
        lines.append(f'  policy file        {res.policy_path or "(not written)"}')
        lines.append(f'  video              {res.video_path or "(not recorded)"}')
        lines.append(f'avg reward for last 100 episodes: {res.mean_last100:.2f}')
        failed += artifact_failures('Q-learning', plot_ok, record_video, res.video_path)

    if cartpole_ns:
        which = 'the Q-learning agent\'s' if q_policy else 'the search\'s'
        lines.append(f'cartpole_sim + cartpole_controller: {which} saved policy drives the cart-pole, then a push')
        if q_policy or search_policy:
            loop, loop_failed = closed_loop(cartpole_ns.rstrip('/'), q_policy or search_policy, balance_steps, push)
            lines += loop
            failed += [f'cart-pole: {f}' for f in loop_failed]
        else:
            lines.append('  no policy file to drive with')
            failed.append('cart-pole: no policy file to drive with')
    if reach_ns:
        lines.append(f'reach: ARS learns to reach on the demo\'s arm, then the arm reaches {reach_goals} seeded goals '
                     f'through ROS (arm_sim, forward_kinematics, reach_controller), each from home')
        reach_lines, reach_failed = reach(reach_ns.rstrip('/'), reach_goals, reach_seed)
        lines += reach_lines
        failed += [f'reach: {f}' for f in reach_failed]
    if failed:
        lines.append('verdict: FAILED - ' + '; '.join(failed))
    else:
        lines.append('verdict: OK - frames move, the search balanced the pole, the Q-learning agents learned'
                     + (', the saved policy balanced the cart-pole robot' if cartpole_ns else '')
                     + (f', the arm reached {reach_goals} of {reach_goals} goals through ROS' if reach_ns else ''))
    lines.append('=' * 72)
    print('\n'.join(lines))
    sys.stdout.flush()
    sys.exit(1 if failed else 0)
