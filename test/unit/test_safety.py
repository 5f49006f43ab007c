"""The safety layer (robot_ai.reach.safety) and the trajectory follower (robot_ai.reach.trajectory), no roscore:
hostile targets on every reference arm, executed as a joint_trajectory_controller executes them, pass no position,
velocity or acceleration limit and touch nothing."""
from __future__ import annotations

import copy
import itertools
import os

import numpy as np
import pytest

from robot_ai.reach.arm import ReachError
from robot_ai.reach.env import ReachSetup
from robot_ai.reach.safety import (LEAD_PERIODS, MAX_LEAD_PERIODS, READY_WITHIN, Limits, SafetyLayer, measure_lead,
                                   read_joint_limits, step_end, stop_from, violations)
from robot_ai.reach.trajectory import ArmBounds, Follower, TrajectoryError

ROBOTS = os.path.realpath(os.path.join(os.path.dirname(__file__), '..', '..', '..', 'shared', 'robots'))
WORLD = os.path.realpath(os.path.join(os.path.dirname(__file__), '..', 'world.yaml'))
PERIOD = 0.05


def setup_of(name: str, **kwargs) -> ReachSetup:
    path = os.path.join(ROBOTS, f'{name}.urdf')
    if not os.path.exists(path):
        pytest.fail(f'{path} is missing: the reference robots are part of the test set-up')
    return ReachSetup(path, **kwargs)


@pytest.fixture(scope='module')
def kuka_world():
    return setup_of('kuka_lwr_arm', obstacles=WORLD)


# ------------------------------------------------------------------------------------------------------- limits
def test_limits_are_the_urdf_s_scaled_and_joint_limits_yaml_only_narrows_them(tmp_path):
    setup = setup_of('kuka_lwr_arm')
    arm = setup.arm
    urdf = Limits.of(arm, velocity_scale=1.0)
    np.testing.assert_array_equal(urdf.velocity, arm.velocity)
    np.testing.assert_array_equal(urdf.lower, arm.lower)
    assert urdf.notes and 'no acceleration limit' in urdf.notes[0]
    half = Limits.of(arm, velocity_scale=0.5)
    np.testing.assert_allclose(half.velocity, arm.velocity * 0.5)
    np.testing.assert_allclose(half.acceleration, urdf.acceleration * 0.5)
    j0, j1 = arm.joints[0], arm.joints[1]
    yaml_file = tmp_path / 'joint_limits.yaml'
    yaml_file.write_text(f'''joint_limits:
  {j0}:
    has_velocity_limits: true
    max_velocity: 0.5
    has_acceleration_limits: true
    max_acceleration: 2.0
    has_position_limits: true
    min_position: -1.0
    max_position: 9.0
  {j1}:
    has_velocity_limits: true
    max_velocity: 99.0
  panda_finger_joint1:
    has_velocity_limits: true
    max_velocity: 0.1
''')
    given = Limits.of(arm, str(yaml_file), velocity_scale=0.5, acceleration_scale=0.25)
    assert given.velocity[0] == pytest.approx(0.25) and given.acceleration[0] == pytest.approx(0.5)
    assert given.lower[0] == -1.0 and given.upper[0] == arm.upper[0]          # narrowed, never widened
    assert given.velocity[1] == pytest.approx(arm.velocity[1] * 0.5)          # 99 > the URDF's: the URDF's
    acceleration = next(n for n in given.notes if 'no acceleration limit' in n)
    assert j0 not in acceleration and j1 in acceleration
    assert 'joint_limits: panda_finger_joint1 is no joint of this robot: left out' in given.notes   # issue 55: said


@pytest.mark.parametrize('text, words', [
    ('joint_limits: [1, 2]', 'MoveIt'),
    ('{a: 1}', 'MoveIt'),
    ('joint_limits: {j: {has_velocity_limits: yes please}}', 'true or false'),
    ('joint_limits: {j: {has_velocity_limits: true, max_velocity: -1}}', 'positive number'),
    ('joint_limits: {j: {has_velocity_limits: true, max_velocity: .nan}}', 'positive number'),
    ('joint_limits: {j: {min_position: .inf}}', 'finite'),
    ('joint_limits: {j: 3}', 'mapping'),
    ('joint_limits: {: [}', 'not YAML'),
    ('/no/such/joint_limits.yaml', 'cannot read'),
])
def test_a_bad_joint_limits_file_is_one_line(text, words):
    with pytest.raises(ReachError) as e:
        read_joint_limits(text)
    assert words in str(e.value) and '\n' not in str(e.value)


def test_a_limit_without_its_has_flag_is_no_limit_as_moveit_reads_it():
    """Issue 57: panda_moveit_config's joint_limits.yaml gives `max_acceleration: 0` beside
    `has_acceleration_limits: false`, which MoveIt reads as no limit; it was refused as not a positive number."""
    arm = setup_of('ur5').arm
    j0, j1 = arm.joints[0], arm.joints[1]
    given = read_joint_limits(f'''joint_limits:
  {j0}: {{has_velocity_limits: true, max_velocity: 2.175, has_acceleration_limits: false, max_acceleration: 0}}
  {j1}: {{max_velocity: -5, has_acceleration_limits: true, max_acceleration: 3.75}}
''')
    assert given[j0] == {'has_velocity_limits': True, 'max_velocity': 2.175, 'has_acceleration_limits': False}
    assert given[j1] == {'has_acceleration_limits': True, 'max_acceleration': 3.75}
    limits = Limits.of(arm, {'joint_limits': {j0: given[j0]}})
    assert limits.acceleration[0] == pytest.approx(limits.velocity[0] / 0.25)    # the default: no limit was given
    with pytest.raises(ReachError, match='positive number'):                    # with its flag, 0 is refused
        read_joint_limits(f'joint_limits: {{{j0}: {{has_acceleration_limits: true, max_acceleration: 0}}}}')


@pytest.mark.parametrize('scale', [0, -0.5, 1.5, float('nan'), True, 'fast'])
def test_a_scale_outside_0_to_1_is_refused(scale):
    with pytest.raises(ReachError, match='velocity_scale'):
        Limits.of(setup_of('ur5').arm, velocity_scale=scale)


# ------------------------------------------------------------------------------------------------------- plans
def run(setup: ReachSetup, targets, steps: int, seed: int = 0, body=None, late: float = 0.03,
        stale: tuple[float, float] = (0.0, 0.0), scale: float = 1.0):
    """The layer driven by targets(k, q) every period (ticks late by up to `late` s, and some later than a whole
    period), each plan taken by a Follower when it arrives (up to 30 ms after it is made), the arm's state measured
    stale[0] to stale[1] s before the tick (as joint_states come on a loaded machine, stamped with the time they
    describe): the arm's motion sampled every 5 ms, the plans."""
    limits = Limits.of(setup.arm, velocity_scale=scale)
    layer = SafetyLayer(limits, PERIOD, body=body)
    arm = Follower(setup.home)
    rng = np.random.default_rng(seed)
    now, times, positions, plans = 0.0, [], [], []
    for k in range(steps):
        at = now - rng.uniform(*stale)
        q, v = arm.state_at(at)
        plan = layer.plan(now, targets(k, q, rng), q, v, measured_at=at)
        plans.append(plan)
        arrive = now + rng.uniform(0.0, late)
        after = now + PERIOD * (rng.uniform(1.0, 1.4) if rng.random() > 0.05 else rng.uniform(1.5, 4.0))
        for t in np.arange(now, after, 0.005):
            if arrive is not None and t >= arrive:
                arm.take(arrive, plan.start, *plan.points(PERIOD))
                arrive = None
            times.append(t)
            positions.append(arm.state_at(t)[0])
        now = after
    return limits, np.array(times), np.array(positions), plans


HOSTILE = {
    'random goals': lambda lower, upper: (lambda k, q, rng: rng.uniform(lower, upper) if k % 30 == 0 else None),
    'always +1': lambda lower, upper: (lambda k, q, rng: q + 1.0),
    'oscillating': lambda lower, upper: (lambda k, q, rng: q + (1.0 if k % 2 else -1.0)),
    'random': lambda lower, upper: (lambda k, q, rng: q + rng.normal(0.0, 1.0, len(q))),
    'beyond the limits': lambda lower, upper: (lambda k, q, rng: np.where(rng.random(len(q)) < 0.5, lower - 5,
                                                                          upper + 5)),
    'NaN now and then': lambda lower, upper: (lambda k, q, rng: np.where(rng.random(len(q)) < 0.2, np.nan,
                                                                         q + rng.normal(0.0, 0.5, len(q)))),
}


def targets_of(kind: str, setup: ReachSetup):
    fn = HOSTILE[kind](setup.arm.lower, setup.arm.upper)
    held = {}

    def targets(k, q, rng):
        t = fn(k, q, rng)
        if t is None:
            return held['t']
        held['t'] = t
        return t
    return targets


@pytest.mark.parametrize('robot', ['ur5', 'kuka_lwr_arm', 'panda', 'pr2'])
@pytest.mark.parametrize('kind', sorted(HOSTILE))
def test_no_target_makes_the_executed_motion_pass_a_limit(robot, kind):
    setup = setup_of(robot)
    limits, times, positions, plans = run(setup, targets_of(kind, setup), 300, seed=len(kind))
    found = violations(times, positions, limits)
    assert found.total == 0, (found, kind)
    assert np.isfinite(positions).all()
    if kind in ('random goals', 'oscillating', 'random'):
        assert np.abs(np.diff(positions, axis=0)).sum() > 0.5, 'the arm hardly moved'
        if kind != 'oscillating':         # which turns every step: the acceleration limit keeps it slow
            assert found.worst['velocity'][0] > 0.5, 'never near its speed: the layer is slower than it need be'
    if kind == 'NaN now and then':
        assert any('NaN' in p.held for p in plans)


@pytest.mark.parametrize('robot', ['ur5', 'kuka_lwr_arm'])
@pytest.mark.parametrize('kind', ['random goals', 'always +1', 'random'])
def test_late_joint_states_are_compared_with_the_commands_of_their_time(robot, kind):
    """joint_states 0.13-0.19 s late at every step, the arm at up to half its speed: by their stamps the arm is
    where its commands put it, so nothing holds and nothing is planned from the stale state (which, at the
    plans' start, was up to 0.2 rad behind: replanning from there made a 17x acceleration limit)."""
    setup = setup_of(robot)
    limits, times, positions, plans = run(setup, targets_of(kind, setup), 300, seed=3, stale=(0.13, 0.19),
                                          scale=0.5)
    found = violations(times, positions, limits)
    assert found.total == 0, (found, kind)
    assert not [p.held for p in plans if p.held], 'held while the arm followed its commands'
    assert found.worst['velocity'][0] > 0.5, 'never near its speed'


def test_an_arm_on_position_commands_is_compared_with_the_last_command_it_was_sent():
    """A position controller goes to each plan's first point (two periods ahead) as it comes: at full speed that is
    0.3 rad ahead of the plans followed in time, and not a reason to hold."""
    setup = setup_of('ur5')
    limits = Limits.of(setup.arm, velocity_scale=1.0)
    for follows, holds in ((False, False), (True, True)):
        layer = SafetyLayer(limits, PERIOD, follows_plans=follows)
        q, held = setup.home.copy(), []
        for k in range(40):
            t = k * PERIOD
            plan = layer.plan(t, setup.arm.upper, q, measured_at=t)
            held.append(bool(plan.held))
            q = plan.positions[0].copy()          # the command, reached before the next tick
        assert any(held) == holds, (follows, held)


@pytest.mark.parametrize('robot', ['ur5', 'panda'])
def test_step_end_is_the_layer_s_plan_one_period_on_for_one_arm_and_a_batch(robot):
    """What an env models (step_end, element-wise, batched) is the plan the layer sends, at its step's end: from
    random states (at rest, moving, near the limits) toward random targets (inside, beyond the limits, held)."""
    setup = setup_of(robot)
    limits = Limits.of(setup.arm, velocity_scale=0.5)
    layer = SafetyLayer(limits, PERIOD)
    rng = np.random.default_rng(7)
    lower, upper = limits.lower, limits.upper
    cases = []
    for k in range(300):
        p0 = rng.uniform(lower, upper) if k % 3 else np.where(rng.random(len(lower)) < 0.5, lower, upper)
        v0 = rng.uniform(-limits.velocity, limits.velocity) * (k % 4 != 0)
        target = [rng.uniform(lower, upper), p0 + 0.001 * rng.normal(size=len(p0)), lower - 1.0, p0][k % 4]
        cases.append((p0, v0, np.clip(target, lower, upper)))
    kinds = set()
    for p0, v0, target in cases:
        plan = layer._step(0.0, p0, v0, target)
        p, v = step_end(p0, v0, target, limits, PERIOD)
        at = list(plan.times).index(PERIOD)                  # the step's end is one of the plan's points
        np.testing.assert_array_equal(p, plan.positions[at])
        np.testing.assert_array_equal(v, plan.velocities[at])
        kinds.add((bool(np.any(v == 0)), bool(np.any(v != 0))))
    p_t, v_t = step_end(*(np.array(x).T for x in zip(*cases)), limits, PERIOD)       # (n, N): the same numbers
    for i, (p0, v0, target) in enumerate(cases):
        p, v = step_end(p0, v0, target, limits, PERIOD)
        np.testing.assert_array_equal(p_t[:, i], p)
        np.testing.assert_array_equal(v_t[:, i], v)
    assert kinds >= {(True, True)}


def test_in_a_world_the_arm_touches_nothing_and_the_holds_name_the_contact(kuka_world):
    setup = kuka_world
    limits, times, positions, plans = run(setup, targets_of('random goals', setup), 1500, seed=3, body=setup.body)
    assert violations(times, positions, limits).total == 0
    assert not setup.body.in_collision(positions).any()
    held = [p for p in plans if p.contacts]
    assert held, 'random goals among a table and two boxes never met one: the test does not test'
    assert all('box' in ' '.join(p.contacts) or 'table' in ' '.join(p.contacts) or ' - ' in p.contacts[0]
               for p in held)
    assert all('would touch within 0.02 m' in p.held for p in held)


def test_a_reachable_target_is_reached_about_as_fast_as_the_limits_allow():
    setup = setup_of('kuka_lwr_arm')
    limits = Limits.of(setup.arm)
    layer = SafetyLayer(limits, PERIOD)
    target = setup.arm.lower * 0.6 + setup.arm.upper * 0.4
    distance = np.abs(target - setup.home)
    # one joint's time-optimal move: accelerate, cruise, brake
    needed = np.where(distance > limits.velocity ** 2 / limits.acceleration,
                      distance / limits.velocity + limits.velocity / limits.acceleration,
                      2 * np.sqrt(distance / limits.acceleration)).max()
    now, q = 0.0, setup.home.copy()
    while np.abs(q - target).max() > 1e-6:
        layer.plan(now, target, q)
        now += PERIOD
        q = layer.last.state_at(now)[0]
        assert now < 1.5 * needed + 0.5, f'not there after {now:.2f} s; the limits allow {needed:.2f} s'
    assert layer.last.state_at(now + 10)[1].max() == 0.0


def test_a_stop_from_full_speed_brakes_at_the_limit_and_holds():
    setup = setup_of('ur5')
    limits = Limits.of(setup.arm)
    v = limits.velocity * np.where(np.arange(setup.arm.n) % 2, 1.0, -1.0)
    plan = stop_from(1.0, setup.home, v, limits.acceleration)
    rest = plan.rest()
    np.testing.assert_allclose(rest - setup.home, v * np.abs(v) / (2 * limits.acceleration), atol=1e-12)
    assert plan.end == pytest.approx(1.0 + (limits.velocity / limits.acceleration).max())
    t = np.linspace(1.0, plan.end + 0.2, 400)
    assert violations(t, [plan.state_at(x)[0] for x in t], limits).total == 0
    np.testing.assert_array_equal(plan.state_at(plan.end + 1)[1], 0.0)


def test_a_stale_state_a_stop_or_a_nan_state_holds_along_the_stop_already_sent():
    setup = setup_of('kuka_lwr_arm')
    limits = Limits.of(setup.arm)
    layer = SafetyLayer(limits, PERIOD)
    q, now = setup.home.copy(), 0.0
    for _ in range(10):          # up to speed toward the upper limits
        layer.plan(now, setup.arm.upper, q)
        now += PERIOD
        q = layer.last.state_at(now)[0]
    moving = layer.last
    held = layer.plan(now, setup.arm.upper, q, why_not='joint_states is 0.5 s old')
    assert held.held == 'joint_states is 0.5 s old'
    for t in np.linspace(held.start, held.end + 1, 50):       # the same motion as the stop sent before
        np.testing.assert_allclose(held.state_at(t)[0], moving.state_at(t)[0], atol=1e-12)
    nan = layer.plan(now + PERIOD, setup.arm.upper, np.full(setup.arm.n, np.nan))
    assert 'NaN' in nan.held
    np.testing.assert_allclose(nan.rest(), moving.rest(), atol=1e-12)


def test_a_plan_made_too_slowly_is_not_sent_and_the_stop_that_goes_on_instead_is_harmless_however_late():
    """A plan whose making (its collision checks on a loaded machine) ate most of the lead would reach the arm after
    its start: a joint_trajectory_controller (the Follower) splices it in from where the arm is, past the
    acceleration limit. With a clock the layer holds instead: the previous plan's stop, the path the arm is on, so
    that even coming late it changes nothing."""
    setup = setup_of('kuka_lwr_arm')
    limits = Limits.of(setup.arm, velocity_scale=0.5)
    target = setup.home + 0.9 * (setup.arm.upper - setup.home)

    def moving(layer):          # up to speed, every plan taken by the arm in time
        arm, q, now = Follower(setup.home), setup.home.copy(), 0.0
        for _ in range(8):
            plan = layer.plan(now, target, q, clock=lambda: now + 0.001)
            assert not plan.held
            arm.take(now + 0.001, plan.start, *plan.points(PERIOD))
            now += PERIOD
            q = arm.state_at(now)[0]
        return arm, q, now

    def motion(arm, since, until):
        times = np.arange(since, until, 0.002)
        return violations(times, np.array([arm.state_at(t)[0] for t in times]), limits)

    far = np.clip(target + 0.3, setup.arm.lower, setup.arm.upper)    # a new target: the plan differs from the stop
    # without the clock the late plan is sent, and taken 30 ms after its start: a jolt
    layer = SafetyLayer(limits, PERIOD)
    arm, q, now = moving(layer)
    plan = layer.plan(now, far, q)
    arm.take(plan.start + 0.03, plan.start, *plan.points(PERIOD))
    jolt = motion(arm, now, now + 2.0)
    assert jolt.acceleration > 0 and jolt.worst['acceleration'][0] > 1.5, jolt
    # with it, the plan that took 90 ms to make is a hold, which comes as late and changes nothing
    layer = SafetyLayer(limits, PERIOD)
    arm, q, now = moving(layer)
    before = layer.last
    held = layer.plan(now, far, q, clock=lambda: now + 0.09)
    assert 'took 90 ms to make' in held.held and not held.contacts
    for t in np.linspace(held.start, held.end + 0.5, 40):
        np.testing.assert_allclose(held.state_at(t)[0], before.state_at(t)[0], atol=1e-12)
    arm.take(held.start + 0.03, held.start, *held.points(PERIOD))
    found = motion(arm, now, now + 2.0)
    assert found.total == 0, found
    # and one made within READY_WITHIN of the lead is sent
    assert not layer.plan(now + PERIOD, far, arm.state_at(now + PERIOD)[0], clock=lambda: now + PERIOD + 0.05).held


def bounds_of(limits: Limits) -> ArmBounds:
    """What the arm itself can do: its limits before the layer's scales (what arm_sim is given)."""
    return ArmBounds(limits.lower, limits.upper, limits.velocity / limits.velocity_scale,
                     limits.unscaled_acceleration)


@pytest.mark.parametrize('late', [0.03, 0.074, 0.15, 0.25])
@pytest.mark.parametrize('name', ['kuka_lwr_arm', 'ur5', 'panda'])
def test_a_late_trajectory_is_joined_within_the_share_of_the_limits_it_uses(name, late):
    """Issue 55: a trajectory that reached arm_sim 74 ms after its start was spliced in from where the arm was to
    its next point, 17 times the acceleration limit. A follower that knows what its arm can do joins it further on
    instead, within the scaled limits the trajectory was planned with; then it follows the trajectory exactly."""
    setup = setup_of(name)
    limits = Limits.of(setup.arm, velocity_scale=0.5)
    rng = np.random.default_rng(int(late * 1000))
    jolts = []
    for trial in range(3):
        layer = SafetyLayer(limits, PERIOD)
        arm, q, now = Follower(setup.home, bounds_of(limits)), setup.home.copy(), 0.0
        controller = Follower(setup.home)                        # joint_trajectory_controller's splice
        target = rng.uniform(setup.arm.lower, setup.arm.upper)
        for _ in range(10):              # up to speed, every plan in time
            plan = layer.plan(now, target, q)
            for follower in (arm, controller):
                follower.take(now + 0.001, plan.start, *plan.points(PERIOD))
            now += PERIOD
            q = arm.state_at(now)[0]
        other = rng.uniform(setup.arm.lower, setup.arm.upper)     # the late plan turns the other way
        plan = layer.plan(now, other, q)
        assert not plan.held
        on_time = copy.deepcopy(controller)
        on_time.take(plan.start - 0.001, plan.start, *plan.points(PERIOD))
        for follower in (arm, controller):
            follower.take(plan.start + late, plan.start, *plan.points(PERIOD))
        assert arm.joined > plan.start + late
        times = np.arange(now, max(plan.end, arm.joined) + 1.0, 0.002)
        found = violations(times, np.array([arm.state_at(t)[0] for t in times]), limits)
        assert found.total == 0, (name, late, trial, found)
        for t in np.linspace(arm.joined, max(plan.end, arm.joined) + 0.5, 30):      # the plan from where it was joined
            np.testing.assert_allclose(arm.state_at(t)[0], on_time.state_at(t)[0], atol=1e-9)
        jolts.append(violations(times, np.array([controller.state_at(t)[0] for t in times]), limits))
    assert max(j.worst['acceleration'][0] for j in jolts) > 2, jolts      # what the controller's splice does


def test_an_arm_that_is_not_where_its_commands_put_it_is_planned_from_where_it_stands():
    setup = setup_of('ur5')
    layer = SafetyLayer(Limits.of(setup.arm), PERIOD)
    layer.plan(0.0, setup.home + 0.1, setup.home)
    moved = setup.home + 0.5                      # someone else moved it
    first = layer.plan(PERIOD, setup.home + 0.1, moved)
    assert 'away from where its commands put it' in first.held and not layer.resynced   # a late message, maybe
    plan = layer.plan(PERIOD + 0.1, setup.home + 0.1, setup.home + 0.004)           # it was: the next is right
    assert not plan.held
    layer.plan(1.0, setup.home + 0.1, moved)
    plan = layer.plan(1.5, setup.home + 0.1, moved)                                  # it stays there: from there
    assert 'planned from where it stands' in layer.resynced
    np.testing.assert_allclose(plan.positions[0], moved, atol=1e-9)


@pytest.mark.parametrize('gap, words', [(0.01, 'within the 0.02 m margin (lwr_arm_'), (0.05, '')])
def test_a_home_within_the_margin_or_touching_is_said_and_a_clear_one_is_not(tmp_path, gap, words):
    """Issue 55: a home within the margin but not in contact made `going home` refused every 2 s for a minute while
    ~home answered success. reach_controller asks the layer first (clear_of) and refuses ~home with its words (a
    home in contact is refused at start: ReachSetup)."""
    plain = setup_of('kuka_lwr_arm', collision=True)
    centres = plain.body.sphere_centres(plain.home[None])[0]
    moving = np.asarray(plain.body.moving_spheres)
    k = int(moving[np.argmax(centres[moving, 0])])        # the moving sphere farthest along x at home
    surface = centres[k, 0] + plain.body.radii[k]
    world = tmp_path / 'near_home.yaml'
    world.write_text(f'obstacles:\n  - {{sphere: 0.05, position: [{surface + gap + 0.05:.6f}, {centres[k, 1]:.6f}, '
                     f'{centres[k, 2]:.6f}], name: ball}}\n')
    setup = setup_of('kuka_lwr_arm', obstacles=str(world))
    layer = SafetyLayer(Limits.of(setup.arm), PERIOD, body=setup.body, margin=0.02)
    said = layer.clear_of(setup.home)
    assert said.startswith(words) if words else said == '', said
    if words:
        assert 'ball' in said
    beyond = setup.home.copy()
    beyond[0] = setup.arm.upper[0] + 0.1
    assert layer.clear_of(beyond) == f'outside the limits of {setup.arm.joints[0]}'


def test_bad_settings_are_one_line():
    limits = Limits.of(setup_of('ur5').arm)
    for kwargs, words in [(dict(period=0), 'period'), (dict(period=PERIOD, margin=-1), 'margin')]:
        with pytest.raises(ReachError, match=words):
            SafetyLayer(limits, **kwargs)
    with pytest.raises(ReachError, match='no plan to hold'):
        SafetyLayer(limits, PERIOD).plan(0.0, None, np.full(limits.lower.shape, np.nan))


# ------------------------------------------------------------------------------------------------ the follower
def test_the_follower_follows_a_plan_exactly_and_a_new_one_from_its_start():
    setup = setup_of('kuka_lwr_arm')
    layer = SafetyLayer(Limits.of(setup.arm), PERIOD)
    first = layer.plan(0.0, setup.arm.upper, setup.home)
    arm = Follower(setup.home)
    arm.take(0.01, first.start, *first.points(PERIOD))
    for t in np.linspace(0.0, first.end + 0.1, 97):
        np.testing.assert_allclose(arm.state_at(t)[0], first.state_at(t)[0], atol=1e-12)
        np.testing.assert_allclose(arm.state_at(t)[1], first.state_at(t)[1], atol=1e-9)
    second = layer.plan(PERIOD, setup.arm.lower, first.state_at(PERIOD)[0])
    arm.take(PERIOD + 0.001, second.start, *second.points(PERIOD))       # arrives before its start
    for t in np.linspace(0.0, second.start, 20):                          # the first until then
        np.testing.assert_allclose(arm.state_at(t)[0], first.state_at(t)[0], atol=1e-12)
    for t in np.linspace(second.start, second.end + 0.1, 50):
        np.testing.assert_allclose(arm.state_at(t)[0], second.state_at(t)[0], atol=1e-12)


def test_a_late_trajectory_starts_from_where_the_arm_is_and_straight_lines_without_velocities():
    arm = Follower([0.0, 0.0])
    arm.take(1.0, 0.5, [1.0, 2.0], [[1.0, 2.0], [1.0, 0.0]])        # its start 0.5 s past: from now, 1.0
    np.testing.assert_allclose(arm.state_at(1.0)[0], [0.0, 0.0])
    np.testing.assert_allclose(arm.state_at(1.25)[0], [0.5, 1.0])   # halfway to the point at 1.5
    np.testing.assert_allclose(arm.state_at(1.25)[1], [2.0, 4.0])
    np.testing.assert_allclose(arm.state_at(9.0)[0], [1.0, 0.0])
    np.testing.assert_allclose(arm.state_at(9.0)[1], [0.0, 0.0])


@pytest.mark.parametrize('times, positions, velocities, words', [
    ([0.1, 0.1], [[0, 0], [1, 1]], None, 'increase'),
    ([0.1], [[0, np.nan]], None, 'NaN'),
    ([0.1], [[0, 0, 0]], None, 'one position per joint'),
    ([0.1], [[0, 0]], [[0, 0], [1, 1]], 'every point or at none'),
    ([0.1], [[0, 0]], None, 'past'),
    ([], np.zeros((0, 2)), None, 'no point'),
])
def test_a_trajectory_that_cannot_be_followed_is_refused_and_changes_nothing(times, positions, velocities, words):
    arm = Follower([0.0, 0.0])
    arm.take(0.0, 0.0, [1.0], [[1.0, 1.0]])
    before = [arm.state_at(t)[0] for t in (0.5, 2.0)]
    now = 5.0 if words == 'past' else 0.2
    with pytest.raises(TrajectoryError, match=words):
        arm.take(now, 0.0 if words == 'past' else now, times, positions, velocities)
    np.testing.assert_allclose([arm.state_at(t)[0] for t in (0.5, 2.0)], before)


UR_STYLE = """# as ur_description's config/ur5e/joint_limits.yaml: names without _joint, angles in !degrees
joint_limits:
  shoulder_pan:
    has_acceleration_limits: false
    has_position_limits: true
    has_velocity_limits: true
    max_position: !degrees  360.0
    max_velocity: !degrees  90.0
    min_position: !degrees -360.0
  elbow:
    has_velocity_limits: true
    max_velocity: !degrees  45.0
  gripper_finger:
    has_velocity_limits: true
    max_velocity: 0.1
"""


def test_ur_description_s_own_file_is_read_and_names_no_joint_has_are_said(tmp_path):
    """Issue 55: ur_description's joint_limits.yaml was refused for its !degrees tag, and its names (shoulder_pan
    where the URDF says shoulder_pan_joint) matched no joint, so the joints ran at the URDF's limits without a word."""
    arm = setup_of('ur5').arm
    path = tmp_path / 'joint_limits.yaml'
    path.write_text(UR_STYLE)
    limits = Limits.of(arm, str(path), velocity_scale=1.0)
    k, e = arm.joints.index('shoulder_pan_joint'), arm.joints.index('elbow_joint')
    assert limits.velocity[k] == pytest.approx(np.pi / 2) and limits.velocity[e] == pytest.approx(np.pi / 4)
    assert limits.lower[k] == pytest.approx(max(arm.lower[k], -2 * np.pi))
    said = ' | '.join(limits.notes)
    assert 'shoulder_pan -> shoulder_pan_joint' in said and 'elbow -> elbow_joint' in said
    assert 'gripper_finger is no joint of this robot: left out' in said
    with pytest.raises(ReachError, match=r'none of its names \(a, b\) is a joint of this robot'):
        Limits.of(arm, 'joint_limits: {a: {has_velocity_limits: true, max_velocity: 1}, b: {}}')


@pytest.mark.parametrize('value', ['5.0e-324', '1.0e-9', '1.0e+7'])
def test_limits_no_plan_can_use_are_refused_at_start(value):
    """Issue 55: max_acceleration 5e-324 made every plan raise on a NaN, 1e-9 held a stop 1.8e8 rad away."""
    with pytest.raises(ReachError, match='outside what a plan can use') as e:
        read_joint_limits(f'joint_limits: {{j: {{has_acceleration_limits: true, max_acceleration: {value}}}}}')
    assert '\n' not in str(e.value)


def test_files_that_are_no_regular_file_too_large_or_an_alias_bomb_are_one_line_at_once(tmp_path):
    """Issue 55: a FIFO as the obstacles or joint_limits hung train, evaluate and the node; a file over 1 MiB was cut
    at 1 MiB without a word (the obstacles after the cut vanished); 450 bytes of nested anchors took 100 s and
    3.6 GB."""
    import time
    from robot_ai.motion.body import BodyError, parse_obstacles
    fifo = tmp_path / 'world.yaml'
    os.mkfifo(fifo)
    big = tmp_path / 'big.yaml'
    box = '  - {box: [0.1, 0.1, 0.1], position: [2, 2, 2]}\n'
    big.write_text('obstacles:\n' + box * ((1 << 20) // len(box) + 10))
    levels = ['a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]'] + [
        f'{chr(98 + i)}: &{chr(98 + i)} [' + ', '.join(['*' + chr(97 + i)] * 9) + ']' for i in range(8)]
    bomb = '\n'.join(levels)
    assert len(bomb) < 500
    for source, words in ((str(fifo), 'not a regular file'), (str(big), 'more than 1 MiB: refused'),
                          (bomb, 'aliases expanded: refused')):
        t = time.monotonic()
        with pytest.raises(BodyError, match=words) as e:
            parse_obstacles(source)
        assert '\n' not in str(e.value) and time.monotonic() - t < 5.0
    with pytest.raises(ReachError, match='not a regular file'):
        read_joint_limits(str(fifo))


def test_a_state_s_time_is_its_stamp_on_the_node_s_clock_and_its_arrival_otherwise_said_once():
    """Issue 55: joint_states delivered 0.3-0.6 s late with their stamps kept were taken as fresh (their age from the
    arrival): the layer planned from where the arm had been, and the arm moved at 4x its scaled velocity limit."""
    from robot_ai.reach.safety import StampClock
    clock = StampClock()
    assert clock.time_of(99.98, 100.0) == (99.98, '')        # the first stamped state: on the node's clock
    assert clock.time_of(99.4, 100.0) == (99.4, '')          # a state delivered 0.6 s late is 0.6 s old
    assert clock.time_of(10.0, 100.0) == (10.0, '')          # however late: the stamps are ours
    assert clock.time_of(100.2, 100.0) == (100.0, '')        # never from the future
    other = StampClock()
    at, note = other.time_of(1.7e9, 100.0)                   # wall-clock stamps where the node runs on sim time
    assert at == 100.0 and 'another clock' in note and '\n' not in note
    assert other.time_of(1.7e9 + 1, 101.0) == (101.0, '')    # said once
    bare = StampClock()
    at, note = bare.time_of(None, 5.0)
    assert at == 5.0 and 'has no stamps' in note and bare.time_of(None, 6.0) == (6.0, '')


def follow(layer: SafetyLayer, q: np.ndarray, target, steps: int, v=None):
    """The layer driven toward target every period, the arm following each plan exactly from its start: the arm's
    motion sampled every 5 ms, and the plans."""
    arm, now, times, positions, plans = None, 0.0, [], [], []
    for k in range(steps):
        if arm is not None:
            q, v = arm.state_at(now)
        plan = layer.plan(now, target, q, v)
        plans.append(plan)
        arm = Follower(plan.positions[0]) if arm is None else arm
        arm.take(now, plan.start, *plan.points(PERIOD))
        for t in np.arange(now, now + PERIOD, 0.005):
            times.append(t)
            positions.append(arm.state_at(t)[0])
        now += PERIOD
    return np.array(times), np.array(positions), plans


def test_an_arm_outside_a_narrowed_range_is_brought_back_within_the_limits_not_jumped():
    """Issue 55: a joint_limits.yaml that narrows a joint the arm stands outside of: the measured position was
    clipped into the range and the first trajectory jumped there (1 rad at once, 4x velocity, 90x acceleration)."""
    setup = setup_of('ur5')
    arm = setup.arm
    j0 = arm.joints[0]
    limits = Limits.of(arm, {'joint_limits': {j0: {'has_position_limits': True, 'min_position': -0.5,
                                                    'max_position': 0.5}}}, velocity_scale=0.25)
    q = setup.home.copy()
    q[0] = 1.5                                                        # a radian outside the range
    times, positions, plans = follow(SafetyLayer(limits, PERIOD), q, setup.home, 120)
    np.testing.assert_allclose(plans[0].positions[0], q, atol=1e-12)   # from where it stands
    assert not any(p.held for p in plans[1:]), [p.held for p in plans if p.held][:3]
    assert -0.5 - 1e-9 <= positions[-1, 0] <= 0.5 + 1e-9                # back within the range
    assert positions[:, 0].max() <= 1.5 + 1e-12                         # never farther out on its way
    back = int(np.argmax(positions[:, 0] <= 0.5 + 1e-9))
    assert np.all(np.abs(positions[back:, 0]) <= 0.5 + 1e-9)             # and in the range once back in it
    inside = Limits.of(arm, velocity_scale=0.25)       # velocity and acceleration: the range's own joint's limits
    found = violations(times, positions, inside)
    assert found.velocity == 0 and found.acceleration == 0, found


def test_a_state_moving_toward_a_limit_stops_within_it_where_the_arm_can_and_goes_on_after():
    """Issue 55: the first plan, and each resync, was a stop from the measured state that was never checked: an arm
    moving toward a limit got a trajectory 0.044 rad past the URDF's limit, and from then on every goal and ~home
    were refused. Its stop brakes harder, up to the unscaled limit, where that keeps the joint inside; where even
    that cannot, the plans after it only bring the joint back."""
    setup = setup_of('ur5')
    arm = setup.arm
    limits = Limits.of(arm, velocity_scale=0.25)
    q, v = setup.home.copy(), np.zeros(arm.n)
    v[1] = limits.velocity[1]
    q[1] = arm.upper[1] - 0.5 * v[1] ** 2 / limits.acceleration[1]       # half the scaled braking distance left
    layer = SafetyLayer(limits, PERIOD)
    times, positions, plans = follow(layer, q, setup.home, 240, v)
    assert positions[:, 1].max() <= arm.upper[1] + 1e-9                 # braked harder: within the limit
    assert not plans[-1].held and np.abs(positions[-1] - setup.home).max() < 1e-3      # and home after
    fast = Limits.of(arm, velocity_scale=1.0)
    q[1], v[1] = arm.upper[1] - 1e-3, fast.velocity[1]                   # too fast even for the unscaled limit
    times, positions, plans = follow(SafetyLayer(limits, PERIOD), q, setup.home, 240, v)
    over = positions[:, 1].max() - arm.upper[1]
    assert 0 < over <= v[1] ** 2 / (2 * fast.acceleration[1]) + 1e-9      # the least it can pass it by
    assert np.abs(positions[-1] - setup.home).max() < 1e-3               # and home after: nothing refused


# --------------------------------------------------------------------------------------------------------- lead
def test_the_lead_is_measured_against_the_machine_not_fixed(kuka_world):
    """Issue 55: with 5,000 obstacles every plan took 89 ms, over the fixed 60 ms (0.6 of two periods), and the arm
    could not move at all. The lead is now measured at start: plans made as the control loop makes them, timed; a
    machine (or a world) that makes them slowly gets as many periods of lead as leave READY_WITHIN of it, and a line
    that says so. The plans' time is what a clock says: a fake one here, each plan taking `took` seconds."""
    limits = Limits.of(kuka_world.arm, velocity_scale=0.5)

    def fake(took):
        calls = itertools.count()                  # plan k starts at k s and ends `took` later
        return lambda: (n := next(calls)) // 2 + (took if n % 2 else 0.0)

    body = kuka_world.body
    quick = measure_lead(limits, PERIOD, body, home=kuka_world.home, clock=fake(0.001))
    assert quick.lead == pytest.approx(LEAD_PERIODS * PERIOD) and quick.p95 == pytest.approx(0.001)
    assert '100 ms (2 periods) ahead' in quick.note
    slow = measure_lead(limits, PERIOD, body, home=kuka_world.home, clock=fake(0.089))
    assert slow.lead == pytest.approx(3 * PERIOD) and READY_WITHIN * slow.lead >= 0.089
    assert '89.0 ms' in slow.note and '150 ms (3 periods)' in slow.note
    hopeless = measure_lead(limits, PERIOD, body, home=kuka_world.home, clock=fake(2.0))
    assert hopeless.lead == pytest.approx(MAX_LEAD_PERIODS * PERIOD)
    assert 'the longest lead' in hopeless.note and 'not sent' in hopeless.note
    # the real clock on the real world: plans of the KUKA among a table and two boxes fit in the two periods
    real = measure_lead(limits, PERIOD, body, home=kuka_world.home)
    assert 0 < real.p95 and real.lead >= LEAD_PERIODS * PERIOD
