"""robot_ai.motion (OMPL's RRT-Connect over a batched check, TOPP-RA timing) and robot_ai.reach.planning (a reach goal
planned with the arm's body), the plans held to the exact meshes (python-fcl) of the reference arms. No rospy."""
from __future__ import annotations

import os

import numpy as np
import pytest

from robot_ai.motion import JointPlanner, time_path
from robot_ai.reach.env import ReachSetup
from robot_ai.reach.planning import ReachPlanner, follow_through_layer

from exact_meshes import MESHES, ROBOTS, Exact

# a table 8 cm under the base (the UR5's shoulder spheres reach 5 cm below it) and two objects in the workspace
WORLD = [{'box': [2.0, 2.0, 0.05], 'position': [0, 0, -0.105], 'name': 'table'},
         {'box': [0.2, 0.2, 0.5], 'position': [0.45, 0.15, 0.25], 'rpy': [0, 0, 0.5], 'name': 'box'},
         {'sphere': 0.12, 'position': [-0.2, -0.45, 0.4], 'name': 'ball'}]
ARMS = {'ur5.urdf': (None, [1.57, -1.57, 1.57, -1.57, 1.57, 0.0]), 'panda.urdf': ('panda_hand', None),
        'kuka_lwr_arm.urdf': (None, None)}


# ------------------------------------------------------------------------------ the planner on a plane
def wall(q: np.ndarray) -> np.ndarray:
    """Clear everywhere but a wall x in [-0.2, 0.2] from y = -1 to 0.8 (a gap above it)."""
    q = np.atleast_2d(q)
    return ~((np.abs(q[:, 0]) < 0.2) & (q[:, 1] < 0.8))


def within_half_a_spacing_of_clear(q: np.ndarray) -> np.ndarray:
    """The wall's promise to a planner checking every 0.01 (sweep 1): no point of a motion deeper in than 0.005."""
    q = np.atleast_2d(q)
    return ~((np.abs(q[:, 0]) < 0.195) & (q[:, 1] < 0.795))


def segment_clear(a, b, clear, count=2000) -> bool:
    return bool(clear(a + np.linspace(0, 1, count)[:, None] * (b - a)).all())


def test_a_straight_way_is_one_check_and_a_walled_one_goes_round():
    planner = JointPlanner([-1, -1], [1, 1], wall, sweep=1.0, spacing=0.01)
    free = planner.plan([-0.5, 0.9], [[0.5, 0.9]])
    assert free.found and free.how == 'straight' and free.motions == 1
    np.testing.assert_array_equal(free.waypoints, [[-0.5, 0.9], [0.5, 0.9]])
    round_ = planner.plan([-0.5, 0.0], [[0.5, 0.0]], time_limit=5.0)
    assert round_.found and round_.how == 'RRTConnect', round_.reason
    np.testing.assert_array_equal(round_.waypoints[[0, -1]], [[-0.5, 0.0], [0.5, 0.0]])
    assert (round_.waypoints[:, 1] > 0.8).any()                   # through the gap
    for a, b in zip(round_.waypoints[:-1], round_.waypoints[1:]):
        assert segment_clear(a, b, within_half_a_spacing_of_clear)


def test_of_several_goals_the_reachable_one_and_reasons_in_one_line():
    planner = JointPlanner([-1, -1], [1, 1], wall, sweep=1.0, spacing=0.01)
    two = planner.plan([-0.5, 0.0], [[0.0, 0.0], [-0.7, -0.5]])    # the first inside the wall
    assert two.found and two.goal == 1
    assert planner.plan([0.0, 0.0], [[0.5, 0.0]]).reason == 'the start is in contact (or within the margin)'
    assert planner.plan([0.5, 0.0], [[0.0, 0.0]]).reason.startswith('every goal configuration is in contact')
    closed = JointPlanner([-1, -1], [1, 1], lambda q: np.abs(np.atleast_2d(q)[:, 0]) >= 0.2, sweep=1.0)
    shut = closed.plan([-0.5, 0.0], [[0.5, 0.0]], time_limit=0.2)
    assert not shut.found and shut.reason == 'no path found in 0.2 s' and '\n' not in shut.reason


def test_the_same_problem_gets_the_same_path_whatever_was_planned_before_it_or_beside_it():
    """OMPL draws its random numbers from one stream per process: each search is seeded from its problem, so that
    a vector env and gymnasium's SyncVectorEnv (or a node's thread beside a prediction) plan the same ways."""
    import threading
    planner = JointPlanner([-1, -1], [1, 1], wall, sweep=1.0, spacing=0.01)

    def walled(y=0.0):
        return planner.plan([-0.5, y], [[0.5, 0.0]], budget=2000).waypoints
    first = walled()
    assert first is not None and len(first) > 2                 # round the wall: a search, not the straight way
    for y in (-0.3, 0.2, -0.6):                                   # other searches between
        assert walled(y) is not None
    np.testing.assert_array_equal(walled(), first)
    beside = []
    threads = [threading.Thread(target=lambda: beside.append(walled())) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for path in beside:
        np.testing.assert_array_equal(path, first)
    assert not np.array_equal(walled(-0.3), first)               # another problem, another path


def test_a_motion_is_checked_finely_enough_for_its_sweep():
    planner = JointPlanner([-1, -1], [1, 1], wall, sweep=[0.5, 2.0], spacing=0.01)
    assert planner.states(np.zeros(2), np.array([0.1, 0.0])) == 6           # 0.05 m swept, every 1 cm
    assert planner.states(np.zeros(2), np.array([0.0, 0.1])) == 21          # 0.2 m
    # a wall thinner than a coarse step is still found by the fine one
    thin = JointPlanner([-1, -1], [1, 1], lambda q: np.abs(np.atleast_2d(q)[:, 0] - 0.0123) > 0.004, sweep=1.0,
                        spacing=0.004)
    assert not thin.motions_clear(np.array([[-0.5, 0.0]]), np.array([[0.5, 0.0]]))[0]


# ------------------------------------------------------------------------------ timing
def test_timing_keeps_every_limit_starts_and_ends_at_rest_and_ends_exactly():
    waypoints = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.0], [1.0, 1.0, 1.0], [0.2, 1.5, 1.0]])
    v, a = np.array([1.0, 0.5, 2.0]), np.array([2.0, 1.0, 0.5])
    timed = time_path(waypoints, v, a)
    assert timed.how == 'toppra' and timed.duration > 0
    t = np.linspace(0, timed.duration, 5000)
    assert (np.abs(timed.velocities(t)) <= v * (1 + 1e-6)).all()
    assert (np.abs(timed.accelerations(t)) <= a * (1 + 1e-6)).all()
    np.testing.assert_array_equal(timed.positions(timed.duration), waypoints[-1])
    np.testing.assert_allclose(timed.positions(0.0), waypoints[0], atol=1e-12)
    np.testing.assert_allclose(timed.velocities(np.array([0.0, timed.duration])), 0.0, atol=1e-9)
    times, positions, velocities = timed.sample(0.05)
    assert times[-1] == timed.duration and positions.shape == (len(times), 3)


def test_a_timing_that_leaves_the_checked_path_falls_back_to_the_segments_themselves():
    waypoints = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])

    def on_segments(q):          # only the two segments themselves are clear: any rounding of the corner is not
        q = np.atleast_2d(q)
        return bool(((np.abs(q[:, 1]) < 1e-9) | (np.abs(q[:, 0] - 1.0) < 1e-9)).all())
    timed = time_path(waypoints, np.ones(2), np.ones(2), is_clear=on_segments)
    assert timed.how == 'rest to rest'
    t = np.linspace(0, timed.duration, 3001)
    assert on_segments(timed.positions(t))
    assert (np.abs(timed.velocities(t)) <= 1 + 1e-9).all() and (np.abs(timed.accelerations(t)) <= 1 + 1e-9).all()
    np.testing.assert_array_equal(timed.positions(timed.duration), waypoints[-1])


# ------------------------------------------------------------------------------ reach plans with real bodies
@pytest.fixture(params=sorted(ARMS))
def arm_world(request, monkeypatch):
    monkeypatch.setenv('ROS_PACKAGE_PATH', MESHES)
    tip, home = ARMS[request.param]
    setup = ReachSetup(os.path.join(ROBOTS, request.param), tip=tip, home=home, obstacles=WORLD, collision=True)
    assert setup.body.missing == [] or request.param == 'kuka_lwr_arm.urdf'    # its wrist's mesh: a stand-in
    return request.param, setup


def test_plans_among_a_table_and_objects_touch_nothing_by_the_exact_meshes(arm_world):
    """From random starts clear of the world to goals whose drawn configuration is clear by the margin: every one is
    planned, and its timed motion, sampled every 2 ms, keeps the limits and never brings the meshes (python-fcl)
    into contact in a checked pair or with an obstacle."""
    robot, setup = arm_world
    planner = ReachPlanner(setup, time_limit=10.0)        # ample on a loaded machine: the bench measures the times
    exact = Exact(setup.body)
    goals, starts = setup.first_states([np.random.default_rng(100 + i) for i in range(24)])
    usable = planner.clear(goals.T) & planner.clear(starts.T)
    assert usable.sum() >= 6, f'{robot}: the world leaves too few clear problems to test'
    hard = 0
    for i in np.flatnonzero(usable)[:6]:
        goal = setup.goals_of(goals[:, i:i + 1])[:, 0]
        plan = planner.plan(starts[:, i], goal)
        assert plan.found, f'{robot} problem {i}: {plan.reason}'
        hard += plan.path.how != 'straight'
        times, positions, _ = plan.timed.sample(0.002)
        reached = setup.goals_of(positions[-1][:, None])[:, 0]
        assert np.linalg.norm(reached - goal) < setup.task.distance_threshold
        assert (np.abs(plan.timed.velocities(times)) <= planner.limits.velocity * (1 + 1e-6)).all()
        assert (np.abs(plan.timed.accelerations(times)) <= planner.limits.acceleration * (1 + 1e-6)).all()
        poses = setup.body.link_poses(positions)
        assert exact.contacts_along(poses, len(positions)) == [], f'{robot} problem {i}'
        assert not setup.body.in_collision(positions).any()


def test_a_way_ends_well_within_the_goal_not_at_the_edge_of_its_threshold(arm_world):
    """The configurations a way is planned to reach each goal within half the threshold, and so does a planned way's
    end: a search stops all its answers once one is well within, and the others, taken as they were, reached the
    PR2's goals by 4 cm of 5; from there its P-controller's step took the tip into a collision."""
    robot, setup = arm_world
    goals, starts = setup.first_states([np.random.default_rng(300 + i) for i in range(8)])
    well = 0.5 * setup.task.distance_threshold
    for i in range(goals.shape[1]):
        goal = setup.goals_of(goals[:, i:i + 1])[:, 0]
        ends, _ = setup.clear_reaching_configurations(goal, starts[:, i], setup.way_margin, least=8)
        assert len(ends), f'{robot} goal {i}: its own drawn configuration reaches it clear'
        reached = np.linalg.norm(setup.goals_of(ends.T)[:3] - goal[:3, None], axis=0)
        assert (reached < well).all(), f'{robot} goal {i}: {np.round(reached, 3)}'
        way = setup.planned_way(goal, starts[:, i], budget=1500)
        if way.found:
            assert np.linalg.norm(setup.goals_of(way.points[-1][:, None])[:3, 0] - goal[:3]) < well


def test_a_goal_with_no_way_says_why(arm_world):
    robot, setup = arm_world
    planner = ReachPlanner(setup, time_limit=2.0)
    inside = planner.plan(setup.home, [0.45, 0.15, 0.25])
    assert not inside.found and inside.reason == 'the goal is inside box'
    far = planner.plan(setup.home, [5.0, 0.0, 0.3])
    assert not far.found and far.reason.startswith('the goal is beyond the arm\'s reach')
    under = planner.plan(setup.home, [0.3, 0.3, -0.2])          # under the table's top, outside the table: no way
    assert not under.found and under.reason in ('the goal is inside table',) or under.reason.startswith(
        ('no configuration reaches the goal clear', 'the goal is beyond'))


def test_the_env_goes_round_by_a_planned_way_where_its_via_points_find_none(monkeypatch):
    """Reach-v0's recovery (a stalled or blocked arm goes in joint space to a configuration that reaches the goal)
    takes a planned way where its straight and via-point ways touch: the UR5 with its real body among the table and
    two objects reaches more of the same goals from home with it, and the goals it adds are the planner's share."""
    from robot_ai.reach import learn
    monkeypatch.setenv('ROS_PACKAGE_PATH', MESHES)
    tip, home = ARMS['ur5.urdf']
    setup = ReachSetup(os.path.join(ROBOTS, 'ur5.urdf'), tip=tip, home=home, obstacles=WORLD, collision=True)
    with_planner = learn.evaluate(learn.p_controller(setup), setup, 40, 1000, start='home')
    monkeypatch.setattr(ReachSetup, '_planned_way', lambda self, goal, q: None)
    without = learn.evaluate(learn.p_controller(setup), setup, 40, 1000, start='home')
    assert with_planner.success_rate > without.success_rate, (with_planner, without)
    assert with_planner.success_rate >= 0.95 and with_planner.planned > 0
    assert without.planned == 0


def test_a_step_between_two_clear_configurations_through_an_obstacle_is_refused(monkeypatch):
    """The env checks a step's whole motion, not only its end: of random short motions of the Panda among the world
    whose ends are both clear, those whose middle the body model finds in contact are refused by guard (they were
    taken when only the end was checked), and a clear motion is taken as before."""
    monkeypatch.setenv('ROS_PACKAGE_PATH', MESHES)
    setup = ReachSetup(os.path.join(ROBOTS, 'panda.urdf'), tip='panda_hand', obstacles=WORLD, collision=True)
    rng = np.random.default_rng(3)
    a = rng.uniform(setup.arm.lower, setup.arm.upper, (4000, setup.arm.n))
    b = np.clip(a + rng.normal(0, 0.4, a.shape), setup.arm.lower, setup.arm.upper)
    ends_clear = ~setup.body.in_collision(a) & ~setup.body.in_collision(b)
    middle_hit = setup.body.in_collision((a + b) / 2)
    through = np.flatnonzero(ends_clear & middle_hit)
    assert len(through) >= 5, 'the sample finds too few motions through an obstacle to test'
    q, hit = setup.guard(a[through].T, b[through].T)
    assert hit.all() and np.array_equal(q, a[through].T)
    for i in through[:5]:                                        # one arm at a time: the same answer
        assert setup.guard_one(a[i].tolist(), b[i].tolist()) == (a[i].tolist(), True)
    free = np.flatnonzero(ends_clear & ~setup.body.in_collision(
        (a[:, None] + (b - a)[:, None] * np.linspace(0, 1, 50)[None, :, None]).reshape(-1, setup.arm.n)).reshape(
        len(a), 50).any(axis=1))[:50]
    q, hit = setup.guard(a[free].T, b[free].T)
    assert not hit.any() and np.array_equal(q, b[free].T)


def test_a_goal_planned_as_reach_controller_plans_it_is_followed_through_the_safety_layer(arm_world):
    """reach_controller plans a goal first where the arm has a body and follows the way through its safety layer:
    no step of a way found is refused, the arm ends at the goal, and the motion the layer sent never brings the
    meshes (python-fcl) into contact, from random starts among the table and two objects. (Most are found: how many
    is the bench's figure; the UR5's fat spheres leave pockets no way leaves with the margin.)"""
    import copy
    robot, setup = arm_world
    exact = Exact(setup.body)
    drawing = copy.copy(setup)
    drawing.start = 'random'
    goals, starts = drawing.first_states([np.random.default_rng(200 + i) for i in range(24)])
    usable = ~setup.body.in_collision(goals.T, 0.02) & ~setup.body.in_collision(starts.T, 0.02)
    assert usable.sum() >= 5, f'{robot}: the world leaves too few clear problems to test'
    found = 0
    for i in np.flatnonzero(usable)[:5]:
        goal = setup.goals_of(goals[:, i:i + 1])[:, 0]
        followed = follow_through_layer(setup, goal, starts[:, i])
        way, plans, refused, end = followed.way, followed.plans, followed.refused, followed.end
        if not way.found:
            assert way.reason.startswith('no path found in'), f'{robot} problem {i}: {way.reason}'
            continue
        found += 1
        assert refused == 0, f'{robot} problem {i}: {refused} steps of the way refused by the layer'
        assert np.linalg.norm(setup.goals_of(end[:, None])[:, 0] - goal) < setup.task.distance_threshold
        sent = np.vstack([p.samples(0.01) for p in plans])
        assert exact.contacts_along(setup.body.link_poses(sent), len(sent)) == [], f'{robot} problem {i}'
    assert found >= 4, f'{robot}: {found} of 5 goals planned'


def test_a_start_within_the_centimetre_more_is_left_and_the_way_keeps_it_beyond(monkeypatch):
    """A start clear by the layer's margin (2 cm) but not by the centimetre more that ways keep: planned with 2 cm
    alone, the Panda's straight way passed its ball closer than the layer lets it, and the layer refused all 2,994
    steps after its sixth. The way may keep 2 cm within 10 cm of motion from the start and keeps 3 cm beyond: no step
    refused, the goal reached, the meshes untouched."""
    monkeypatch.setenv('ROS_PACKAGE_PATH', MESHES)
    tip, home = ARMS['panda.urdf']
    setup = ReachSetup(os.path.join(ROBOTS, 'panda.urdf'), tip=tip, home=home, obstacles=WORLD, collision=True,
                       start='random')
    goals, starts = setup.first_states([np.random.default_rng(2029)])
    start, goal = starts[:, 0], setup.goals_of(goals)[:, 0]
    assert not setup.body.in_collision(start[None], 0.02)[0] and setup.body.in_collision(start[None], 0.03)[0]
    followed = follow_through_layer(setup, goal, start)
    assert followed.way.found and followed.refused == 0, (followed.way.reason, followed.refused)
    assert np.linalg.norm(setup.goals_of(followed.end[:, None])[:, 0] - goal) < setup.task.distance_threshold
    sent = np.vstack([p.samples(0.01) for p in followed.plans])
    assert Exact(setup.body).contacts_along(setup.body.link_poses(sent), len(sent)) == []


def test_a_way_given_from_outside_is_followed_without_the_limit_recovery(monkeypatch):
    """A policy file from before the limit recovery drives without it, but the way reach_controller plans for it is
    followed all the same (recover_one takes a RECOVERING way whatever limit_recovery is); READY stays the policy's."""
    from robot_ai.reach.env import READY, Recovery
    monkeypatch.setenv('ROS_PACKAGE_PATH', MESHES)
    tip, home = ARMS['ur5.urdf']
    setup = ReachSetup(os.path.join(ROBOTS, 'ur5.urdf'), tip=tip, home=home, obstacles=WORLD, collision=True,
                       limit_recovery=False)
    goals, _ = setup.first_states([np.random.default_rng(7)])
    goal = setup.goals_of(goals)[:, 0]
    followed = follow_through_layer(setup, goal, setup.home)
    way, plans, refused, end = followed.way, followed.plans, followed.refused, followed.end
    assert way.found and refused == 0 and len(plans) > 2
    assert np.linalg.norm(setup.goals_of(end[:, None])[:, 0] - goal) < setup.task.distance_threshold
    q = setup.home.tolist()
    assert setup.recover_one(q, setup.place_one(q)[0], q, [1.0, 0, 0], goal.tolist(), Recovery()) == (q, Recovery())
    assert Recovery().state == READY
