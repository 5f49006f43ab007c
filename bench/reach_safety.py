#!/usr/bin/env python3
"""reach_controller's safety layer against hostile and learned policies, and how fast a click becomes a command:

- In-process, as reach_controller runs it: every 1/20 s (each tick up to 40 % late, one in twenty up to 4 periods
  late) the policy acts on the observation of where the arm stands, the safety layer plans, and the plan is taken
  by the trajectory follower arm_sim runs (robot_ai.reach.trajectory: what joint_trajectory_controller does) up to
  30 ms after it is made. The arm's motion is sampled every 5 ms and checked against the position, velocity and
  acceleration limits (velocity_scale 0.5) and against the arm's body and the world with no margin. Policies: ARS
  trained here, the P-controller on the same action, and hostile ones: always +1, oscillating (the sign flips every
  step), random, and NaN one step in five; every action through the env's recovery as reach_controller runs it (a
  way round a joint limit, a stall or an obstacle, once a goal). --goals goals each (100), on the KUKA LWR among a
  table and two boxes (test/world.yaml) and on the UR5 (limits only: its collision meshes are not on this machine).
- Through ROS (reach.launch command:=trajectory, the UR5, velocity_scale 1): the time from a goal published on
  ~goal to the first trajectory on joint_trajectory_controller/command, with the arm at rest before each click
  (after ~home), quiet and with two busy loops on the cores (started here).

    python bench/reach_safety.py [--goals 100] [--clicks 100] [--seconds 6]
"""
import argparse
import dataclasses
import os
import subprocess
import sys
import threading
import time

import numpy as np

HERE = os.path.dirname(os.path.realpath(__file__))
ROOT = os.path.dirname(HERE)
ROBOTS = os.path.realpath(os.path.join(ROOT, '..', 'shared', 'robots'))
sys.path.insert(0, HERE)
from ros_env_speed import free_port, stop_all  # noqa: E402

PERIOD = 0.05
SCALE = 0.5
EPISODE = 6.0          # seconds of a goal at most (--seconds)


class Hostile:
    """A policy of the reach action space that is not one: act_batch(x) of the kind."""

    def __init__(self, kind: str, size: int, seed: int = 0):
        self.kind, self.size, self.rng, self.k = kind, size, np.random.default_rng(seed), 0

    def act_batch(self, x):
        self.k += 1
        if self.kind == 'always +1':
            return np.ones((len(x), self.size))
        if self.kind == 'oscillating':
            return np.full((len(x), self.size), 1.0 if self.k % 2 else -1.0)
        if self.kind == 'random':
            return self.rng.uniform(-1, 1, (len(x), self.size))
        out = self.rng.uniform(-1, 1, (len(x), self.size))       # NaN one step in five
        if self.rng.random() < 0.2:
            out[:] = np.nan
        return out


def run_goals(setup, policy, goals: int, seed: int, body, seconds: float = EPISODE, late: float = 0.0,
              bounded: bool = True) -> dict:
    """The controller's loop in-process over `goals` goals (see the module): violations, collisions, reached. late:
    the share of plans that reach the arm 0 to 300 ms after their start (a loaded machine), the ones after them no
    sooner (a topic delivers in order); bounded: the arm is arm_sim's follower (joins a late plan within the arm's
    limits), else joint_trajectory_controller's (splices it in from where the arm is)."""
    from robot_ai import ars
    from robot_ai.reach.safety import Limits, SafetyLayer, violations
    from robot_ai.reach.env import Recovery
    from robot_ai.reach.task import goal_distance_one
    from robot_ai.reach.trajectory import ArmBounds, Follower, TrajectoryError
    limits = Limits.of(setup.arm, velocity_scale=SCALE)
    full = Limits.of(setup.arm, velocity_scale=1.0)
    layer = SafetyLayer(limits, PERIOD, body=body)
    moving = setup.through(limits, PERIOD, layer.margin)      # reach_controller's recovery, as it runs it
    arm = Follower(setup.home, ArmBounds(full.lower, full.upper, full.velocity, full.acceleration) if bounded else None)
    pending, last_arrival, late_plans = [], 0.0, 0
    rng = np.random.default_rng(seed)
    now, times, positions = 0.0, [], []
    reached = held = 0
    for _ in range(goals):
        while True:
            q = rng.uniform(setup.arm.lower, setup.arm.upper)
            if body is None or not body.in_collision(q[None], 0.03)[0]:
                break
        goal = setup.arm.tip_positions(q[None])[0].tolist()
        end = now + seconds
        recovery = Recovery()
        while now < end:
            p, v = arm.state_at(now)
            tip = setup.place_one(p.tolist())[0]
            if goal_distance_one(tip, goal) < setup.task.distance_threshold:
                reached += 1
                break
            obs = setup.observation_one(p.tolist(), tip, goal)
            action = policy.act_batch(ars.flatten_batch(setup.observation_space, {k: x[None] for k, x in
                                                                                  obs.items()}))[0]
            action = np.asarray(action, dtype=float)
            if np.isfinite(action).all():
                a = setup.check_action_one(action)
                moved = setup.move_one(p.tolist(), setup.place_one(p.tolist())[1], a)
                target, recovery = moving.recover_one(p.tolist(), tip, moved, a, goal, recovery)
                plan = layer.plan(now, target, p, v)
                if plan.held:         # reach_controller's rule: a step a collision refuses gives a way round up and
                    recovery = (recovery.give_up() if plan.contacts    # is one without progress; others no step
                                else dataclasses.replace(recovery, since=0))
            else:
                plan = layer.plan(now, None, p, v, why_not='the policy gave no action')
            held += bool(plan.held)
            arrive = now + rng.uniform(0.0, 0.03)
            if late and rng.random() < late:
                arrive, late_plans = plan.start + rng.uniform(0.0, 0.3), late_plans + 1
            last_arrival = max(arrive, last_arrival)
            pending.append((last_arrival, plan))
            after = now + PERIOD * (rng.uniform(1.0, 1.4) if rng.random() > 0.05 else rng.uniform(1.5, 4.0))
            for t in np.arange(now, after, 0.005):
                while pending and t >= pending[0][0]:
                    when, due = pending.pop(0)
                    try:
                        arm.take(when, due.start, *due.points(PERIOD))
                    except TrajectoryError:          # every point in the past: refused, as a controller does
                        pass
                times.append(t)
                positions.append(arm.state_at(t)[0])
            now = after
    positions = np.array(positions)
    found = violations(np.array(times), positions, limits)
    touching = int(body.in_collision(positions).sum()) if body is not None else 0
    return dict(found=found, arm=violations(np.array(times), positions, full), touching=touching,
                samples=len(times), reached=reached, held=held, seconds=now, late=late_plans)


def in_process(goals: int, seconds: float = EPISODE) -> None:
    from robot_ai.reach import learn
    from robot_ai.reach.env import ReachSetup
    world = os.path.join(ROOT, 'test', 'world.yaml')
    for name, kwargs in (('kuka_lwr_arm', dict(obstacles=world)), ('ur5', dict(collision=True))):
        model = os.path.join(ROBOTS, f'{name}.urdf')
        setup = ReachSetup(model, **kwargs)
        body = setup.body if setup.body is not None and len(setup.body.radii) else None
        t = time.monotonic()
        training = learn.train(dict(model=model, **({'obstacles': world} if 'obstacles' in kwargs else {})), seed=0)
        trained = time.monotonic() - t
        where = "a table and two boxes, the arm's body" if body else 'limits only'
        print(f'  {setup.model.tree.name} ({where}), '
              f'{goals} goals a policy, {seconds:g} s a goal, velocity_scale {SCALE}; ARS trained in {trained:.1f} s')
        print(f'    {"policy":16s} {"limits passed (pos/vel/acc)":>28s} {"contacts":>9s} {"reached":>8s} '
              f'{"holds":>6s} {"samples":>8s}  worst velocity, acceleration (share of the limit)')
        size = setup.action_space.shape[0]
        policies = [('ARS', training.policy), ('P-controller', learn.p_controller(setup))]
        policies += [(kind, Hostile(kind, size, seed=k)) for k, kind in
                     enumerate(('always +1', 'oscillating', 'random', 'NaN 1 step in 5'))]
        for label, policy in policies:
            r = run_goals(setup, policy, goals, seed=7, body=body, seconds=seconds)
            f = r['found']
            worst = f'{f.worst["velocity"][0]:.3f}, {f.worst["acceleration"][0]:.4f}'
            print(f'    {label:16s} {f"{f.position}/{f.velocity}/{f.acceleration}":>28s} {r["touching"]:>9d} '
                  f'{r["reached"]:>4d}/{goals:<3d} {r["held"]:>6d} {r["samples"]:>8,d}  {worst}')
        late_goals = max(goals // 4, 1)
        print(f'    one plan in ten 0-300 ms after its start (a loaded machine), {late_goals} goals a policy: the '
              f'worst velocity, acceleration as shares of the arm\'s own limits (the layer\'s are {SCALE:g} of them)')
        print(f'    {"policy":16s} {"late plans":>10s} {"arm_sim (joins within the limits)":>36s} '
              f'{"joint_trajectory_controller (splices)":>40s}')
        for label, policy in policies[:1] + policies[2:4]:
            cells = []
            for bounded in (True, False):
                if isinstance(policy, Hostile):
                    policy.rng, policy.k = np.random.default_rng(0), 0
                r = run_goals(setup, policy, late_goals, seed=11, body=body, seconds=seconds, late=0.1,
                              bounded=bounded)
                a = r['arm']
                cells.append(f'{a.worst["velocity"][0]:.3f}, {a.worst["acceleration"][0]:.3f} '
                             f'({a.velocity + a.acceleration} passed)')
            print(f'    {label:16s} {r["late"]:>10d} {cells[0]:>36s} {cells[1]:>40s}')


# ------------------------------------------------------------------------------------------------- attacks
STATE_TIMEOUT = 0.2     # reach_controller's ~state_timeout
SAMPLE = 0.005          # s between two samples of the arm's motion


def attack(limits, start_q, start_v, target, late: tuple[float, float], steps: int = 200, seed: int = 0):
    """The layer toward target from a measured state (start_q, start_v), each tick's joint_states measured late[0]
    to late[1] s before it (stamped with the time they describe) and held, as reach_controller holds, once older
    than STATE_TIMEOUT; the arm follows the plans exactly (each from its start on, from the stop of the measured
    state before the first): (the worst velocity and acceleration of its motion as shares of the limits, the
    samples farther out than the position limits, or than the start where it stood outside them)."""
    from robot_ai.reach.safety import SafetyLayer, violations
    layer = SafetyLayer(limits, PERIOD)
    rng = np.random.default_rng(seed)

    def arm_at(t: float):
        return next((p.state_at(t) for p in reversed(layer.history) if p.start <= t), layer.history[0].state_at(t))
    now, times, positions = 0.0, [], []
    for k in range(steps):
        at = now - rng.uniform(*late)
        if k == 0:
            layer.plan(now, target, np.array(start_q, dtype=float), np.array(start_v, dtype=float))
        elif now - at > STATE_TIMEOUT:
            layer.plan(now, None, None, why_not='joint_states is old')
        else:
            layer.plan(now, target, *arm_at(max(at, 0.0)), measured_at=at)
        while len(times) * SAMPLE < now + PERIOD - 1e-9:      # one grid of samples: no two at one time
            times.append(len(times) * SAMPLE)
            positions.append(arm_at(times[-1])[0])
        now += PERIOD
    positions = np.array(positions)
    found = violations(np.array(times), positions, limits)
    # farther out than the limits, or than the start where it stood outside them (a narrowed range)
    lower = np.minimum(limits.lower, start_q) - 1e-9
    upper = np.maximum(limits.upper, start_q) + 1e-9
    farther = int(((positions < lower) | (positions > upper)).any(axis=1).sum())
    return found.worst['velocity'][0], found.worst['acceleration'][0], farther


def attacks() -> None:
    """Issue 55's inputs that took the arm past its limits, in-process on the UR5 at velocity_scale 0.25: the worst
    velocity and acceleration of the motion as shares of the limits (1.0 is the goal), the position limits passed."""
    from robot_ai.reach.env import ReachSetup
    from robot_ai.reach.safety import Limits
    setup = ReachSetup(os.path.join(ROBOTS, 'ur5.urdf'))
    arm = setup.arm
    limits = Limits.of(arm, velocity_scale=0.25)
    narrowed = Limits.of(arm, {'joint_limits': {arm.joints[0]: {'has_position_limits': True, 'min_position': -0.5,
                                                                 'max_position': 0.5}}}, velocity_scale=0.25)
    rest, outside = setup.home.copy(), setup.home.copy()
    outside[0] = 1.5
    toward, v = setup.home.copy(), np.zeros(arm.n)
    v[1] = limits.velocity[1]
    toward[1] = arm.upper[1] - 0.25 * v[1] ** 2 / limits.acceleration[1]   # half the scaled braking distance left
    still = np.zeros(arm.n)
    cases = [('joint_states 0.3-0.6 s late', limits, rest, still, rest + 0.8, (0.3, 0.6)),
             ('joint_states 0-0.15 s late', limits, rest, still, rest + 0.8, (0.0, 0.15)),
             ('outside a narrowed range', narrowed, outside, still, rest, (0.0, 0.05)),
             ('moving toward a limit', limits, toward, v, rest, (0.0, 0.05))]
    print(f'  attacks on the layer\'s input, in-process ({arm.tree.name}, velocity_scale 0.25, the arm following each '
          f'plan from its start); worst velocity and acceleration as shares of the scaled limits, 1.0 the goal')
    print(f'    {"input":30s} {"worst velocity":>15s} {"worst acceleration":>19s} {"samples farther out":>20s}')
    for label, lim, q, v0, target, late in cases:
        wv, wa, passed = attack(lim, q, v0, target, late)
        print(f'    {label:30s} {wv:>15.3f} {wa:>19.3f} {passed:>20d}')
    print('    (moving toward a limit with half the braking distance it needs at the scaled acceleration left: its')
    print('     stop brakes at twice the scaled, half the unscaled limit, and stays within the position limit)')


# ------------------------------------------------------------------------------------------------- through ROS
def click_latencies(clicks: int, node: str = '/reach_controller') -> np.ndarray:
    """Seconds from a goal published to the first trajectory command after it, the arm at rest before each."""
    import rospy
    from geometry_msgs.msg import PointStamped
    from std_srvs.srv import Trigger
    from trajectory_msgs.msg import JointTrajectory
    from robot_ai.reach.env import ReachSetup
    setup = ReachSetup(os.path.join(ROBOTS, 'ur5.urdf'))
    seen, got = [], threading.Condition()

    def on_command(msg):
        with got:
            seen.append(time.monotonic())
            got.notify_all()
    sub = rospy.Subscriber('/joint_trajectory_controller/command', JointTrajectory, on_command, queue_size=100,
                           tcp_nodelay=True)
    pub = rospy.Publisher(f'{node}/goal', PointStamped, queue_size=1, tcp_nodelay=True)
    home = rospy.ServiceProxy(f'{node}/home', Trigger)
    time.sleep(1.0)
    rng = np.random.default_rng(5)
    out = []
    for _ in range(clicks):
        home()
        quiet = time.monotonic()
        while True:                               # at rest: no command for 0.3 s
            time.sleep(0.05)
            with got:
                last = seen[-1] if seen else 0.0
            if time.monotonic() - max(last, quiet) > 0.3:
                break
        q = rng.uniform(setup.arm.lower, setup.arm.upper)
        msg = PointStamped()
        msg.header.frame_id = setup.arm.base
        msg.point.x, msg.point.y, msg.point.z = setup.arm.tip_positions(q[None])[0]
        with got:
            before = len(seen)
            sent = time.monotonic()
            pub.publish(msg)
            got.wait_for(lambda: len(seen) > before, timeout=5.0)
            if len(seen) > before:
                out.append(seen[before] - sent)
    sub.unregister()
    pub.unregister()
    return np.array(out)


def through_ros(clicks: int) -> None:
    port = free_port()
    env = dict(os.environ, ROS_MASTER_URI=f'http://127.0.0.1:{port}')
    os.environ['ROS_MASTER_URI'] = env['ROS_MASTER_URI']
    procs = [subprocess.Popen(['roslaunch', '-p', str(port), 'robot_ai', 'reach.launch', 'rviz:=false',
                               'command:=trajectory', 'velocity_scale:=1.0'], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, preexec_fn=os.setsid)]
    try:
        import rosgraph
        import rospy
        deadline = time.time() + 60
        while not rosgraph.Master('/reach_safety_bench').is_online() and time.time() < deadline:
            time.sleep(0.2)
        rospy.init_node('reach_safety_bench', disable_signals=True)
        rospy.wait_for_service('/reach_controller/home', 300)
        print(f'  a click to the first trajectory command, through ROS (reach.launch command:=trajectory, UR5), '
              f'{clicks} clicks, the arm at rest before each (ms)')
        for label, loops in (('quiet', 0), ('two busy loops', 2)):
            busy = [subprocess.Popen([sys.executable, '-c', 'while True: pass']) for _ in range(loops)]
            try:
                waits = click_latencies(clicks) * 1000
            finally:
                for b in busy:
                    b.kill()
                    b.wait()
            print(f'    {label:15s} p50 {np.percentile(waits, 50):6.1f}   p99 {np.percentile(waits, 99):6.1f}   '
                  f'max {waits.max():6.1f}   ({len(waits)} of {clicks} answered within 5 s)')
    finally:
        stop_all(procs)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--goals', type=int, default=100, help='goals for each policy, in-process')
    parser.add_argument('--clicks', type=int, default=100, help='clicks through ROS, each load')
    parser.add_argument('--seconds', type=float, default=EPISODE, help='seconds a goal at most, in-process')
    a = parser.parse_args()
    print(f'reach_controller\'s safety layer, {os.cpu_count()} cores (load average {os.getloadavg()[0]:.2f})   '
          f'[bench/reach_safety.py, {time.strftime("%Y-%m-%d")}]')
    in_process(a.goals, a.seconds)
    attacks()
    if a.clicks:
        through_ros(a.clicks)
    return 0


if __name__ == '__main__':
    sys.exit(main())
