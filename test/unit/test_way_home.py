"""reach_controller's way home for a retry (_way_home): straight in joint space when that way is clear of contacts,
else back the way the arm came up to where a straight way is; every configuration of it clear, none further apart
than the arm's own trail, and home at its end. Before, the arm retraced all of the way it came (45 s at 0.25 after
a way round, a user saw)."""
import os
from types import SimpleNamespace

import numpy as np
import pytest

from robot_ai.nodes.reach_controller import AT_HOME, TRAIL_STEP, ReachController
from robot_ai.reach.env import ReachSetup
from robot_ai.reach.safety import Limits, SafetyLayer

HERE = os.path.dirname(os.path.realpath(__file__))
KUKA = os.path.realpath(os.path.join(HERE, '..', '..', '..', 'shared', 'robots', 'kuka_lwr_arm.urdf'))
WORLD = os.path.realpath(os.path.join(HERE, '..', 'world.yaml'))


@pytest.fixture(scope='module')
def node():
    setup = ReachSetup(KUKA, obstacles=WORLD)
    layer = SafetyLayer(Limits.of(setup.arm, velocity_scale=0.25), 0.05, body=setup.body, margin=0.02)
    return SimpleNamespace(setup=setup, layer=layer)


def line(a, b):
    steps = max(1, int(np.ceil(np.abs(b - a).max() / TRAIL_STEP)))
    return [a + f * (b - a) for f in np.linspace(0.0, 1.0, steps + 1)]


def clear(node, qs, margin=0.02):
    return not node.setup.body.in_collision(np.array(qs), margin).any()


def followed(way, q, home):
    """The configurations the arm is sent to, in order (the trail is followed from its end), home last."""
    return [np.array(q)] + [np.array(p) for p in reversed(way)] + [home]


def way_home(node, q, trail):
    """(the way home from q, the configurations the arm goes through on it), checked clear of contacts with the
    layer's margin and never more than TRAIL_STEP between two."""
    way, _ = ReachController._way_home(node, q.tolist(), [p.tolist() for p in trail])
    path = followed(way, q, node.setup.home)
    assert clear(node, path)
    assert max(np.abs(b - a).max() for a, b in zip(path, path[1:])) <= TRAIL_STEP + 1e-9
    return way, path


def test_a_clear_straight_way_home_is_taken_whatever_way_the_arm_came(node):
    home = node.setup.home
    rng = np.random.default_rng(0)
    while True:                     # a detour out and a configuration whose straight way home is clear
        q, detour = (rng.uniform(node.setup.arm.lower, node.setup.arm.upper) for _ in range(2))
        trail = line(home, detour) + line(detour, q)
        if clear(node, trail) and clear(node, line(q, home)) and len(trail) > 3 * len(line(q, home)):
            break
    way, _ = way_home(node, q, trail)
    np.testing.assert_allclose(way[0], home, atol=1e-12)
    assert len(way) < len(trail) / 2                                 # not back the way it came


def test_where_the_straight_way_touches_it_goes_back_the_way_it_came_as_far_as_it_must(node):
    home = node.setup.home
    rng = np.random.default_rng(1)
    for _ in range(20000):          # q whose straight way home touches the world, reached by a clear detour
        q, detour = (rng.uniform(node.setup.arm.lower, node.setup.arm.upper) for _ in range(2))
        trail = line(home, detour) + line(detour, q)
        if not clear(node, line(q, home)) and clear(node, trail):
            break
    else:
        pytest.fail('no configuration of the KUKA among test/world.yaml whose straight way home touches')
    way, path = way_home(node, q, trail)
    assert len(way) <= len(trail) + 1


def test_without_a_body_the_way_is_the_trail_as_it_was(node):
    bare = SimpleNamespace(setup=node.setup, layer=SafetyLayer(node.layer.limits, 0.05))
    trail = [node.setup.home.tolist(), (node.setup.home + 0.1).tolist()]
    assert ReachController._way_home(bare, trail[-1], trail) == (trail, 2)


def test_the_ways_of_earlier_goals_are_not_retraced(node):
    """The trail holds every goal's way since the arm was last at home: an earlier goal's detour out and back is
    skipped when a straight way reaches the trail after it."""
    home = node.setup.home
    rng = np.random.default_rng(2)
    draw = lambda: rng.uniform(node.setup.arm.lower, node.setup.arm.upper)   # noqa: E731
    for _ in range(20000):
        a, b, q = draw(), draw(), draw()
        detour = line(home, a) + line(a, home)           # an earlier goal, there and back
        trail = detour + line(home, b) + line(b, q)
        if not clear(node, line(q, home)) and clear(node, trail) and clear(node, line(q, b)):
            break
    else:
        pytest.fail('no such ways among test/world.yaml')
    way, path = way_home(node, q, trail)
    at_home = [i for i, p in enumerate(path) if np.abs(p - home).max() < AT_HOME]   # where the retry starts
    assert at_home and at_home[0] <= len(line(home, b)) + len(line(b, q)), (at_home[:1], len(detour), len(trail))
