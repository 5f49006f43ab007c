"""A pick and place as rviz asks for it (physics.pick), in-process: the arm driven through the safety layer in the
MuJoCo world arm_sim runs (the plans followed in time, the gripper's goals), on the package's UR5 with a Robotiq
2F-85 and the Panda with its real meshes: the cube placed where the click says, what the physics measured on the way
(no joint past its URDF velocity or position limits, no contact but the fingers' with the cube), the world the
`world` command writes (and pick.launch's default, config/pick_world.yaml, equal to it), and clicks that cannot be
picks said in one line. No roscore."""
from __future__ import annotations

import os

import numpy as np
import pytest
import yaml

from robot_ai.motion.body import parse_obstacles
from robot_ai.physics import parse_objects
from robot_ai.physics.__main__ import main
from robot_ai.physics.env import ManipulationSetup
from robot_ai.physics.model import build_physics
from robot_ai.physics.pick import CARRY, PickError, PickPlace, run_in_physics, world
from robot_ai.physics.sim import ArmPhysics
from robot_ai.physics.workspace import finger_links

from exact_meshes import MESHES, ROBOTS

PACKAGE = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', '..')
ROBOTIQ = os.path.join(PACKAGE, 'urdf', 'ur5_robotiq_2f85.urdf.xacro')
PANDA = os.path.join(ROBOTS, 'panda.urdf')
SETUPS = {}


@pytest.fixture(autouse=True)
def meshes(monkeypatch):
    """The Panda's real meshes for every model and body a test builds (the setups are kept across tests: setup_of sets
    the path for itself too)."""
    monkeypatch.setenv('ROS_PACKAGE_PATH', os.pathsep.join((MESHES, os.environ.get('ROS_PACKAGE_PATH', ''))))


def setup_of(model: str) -> ManipulationSetup:
    if model not in SETUPS:
        with pytest.MonkeyPatch.context() as mp:      # the Panda's real meshes, also in a module-scoped use
            mp.setenv('ROS_PACKAGE_PATH', os.pathsep.join((MESHES, os.environ.get('ROS_PACKAGE_PATH', ''))))
            SETUPS[model] = ManipulationSetup('pick_and_place', model=model)
    return SETUPS[model]


def picking_in(setup: ManipulationSetup, made: dict, **kwargs) -> tuple[PickPlace, ArmPhysics]:
    physics = build_physics(setup.robot, obstacles=made['obstacles'], objects=made['objects'], home=made['home'])
    return PickPlace(setup, obstacles=made['obstacles'], **kwargs), ArmPhysics(physics, setup.arm.joints)


@pytest.mark.parametrize('model', [ROBOTIQ, PANDA], ids=['ur5_robotiq', 'panda'])
def test_a_clicked_pick_places_the_cube_within_the_limits_touching_nothing_else(model):
    setup = setup_of(model)
    hand = set(finger_links(setup.robot.tree, setup.gripper)) | set(setup.robot.tree.subtree(setup.arm.tip))
    rng = np.random.default_rng(5)
    for seed in range(3):
        made = world(setup, 1, seed)
        picking, arm = picking_in(setup, made)
        if seed == 2:           # from elsewhere than the ready configuration: a planned way there first
            arm.set_state(setup.space.ready + rng.uniform(-0.3, 0.3, setup.arm.n))
        place = [*(setup.space.centre[:2] + rng.uniform(-0.15, 0.15, 2)), setup.space.table_top]
        run = run_in_physics(picking, arm, 'cube', place)
        assert run.outcome.startswith('placed cube'), run
        cube = arm.object_poses()['cube'][:3, 3]
        np.testing.assert_allclose(cube, np.add(place, [0, 0, setup.object_size / 2]), atol=0.012)
        assert run.fastest < 1.0 and run.within_limits, run        # the layer's limits held by the servos
        touched = {c.split(' - ')[0] for c in run.contacts}
        assert touched and touched <= hand and all(c.endswith(' - cube') for c in run.contacts), run.contacts


def test_the_world_command_writes_what_arm_sim_and_pick_place_take(tmp_path):
    setup = setup_of(ROBOTIQ)
    made = world(setup, 3, seed=1)
    table = setup.table()
    assert made['obstacles'][0]['box'] == table['box']
    np.testing.assert_allclose(made['obstacles'][0]['position'], table['position'], atol=1e-4)
    cubes = np.array([o['position'] for o in made['objects']])
    assert [o['name'] for o in made['objects']] == ['cube', 'cube_2', 'cube_3']
    assert (np.abs(cubes[:, :2] - setup.space.centre[:2]) <= setup.obj_range / 2 + 1e-4).all()
    np.testing.assert_allclose(cubes[:, 2], setup.space.table_top + setup.object_size / 2, atol=1e-4)
    gaps = [np.linalg.norm(a[:2] - b[:2]) for i, a in enumerate(cubes) for b in cubes[i + 1:]]
    assert min(gaps) >= 0.1
    np.testing.assert_allclose(list(made['home'].values()), setup.space.ready, atol=1e-6)
    out = tmp_path / 'world.yaml'
    assert main(['world', '--model', ROBOTIQ, '--output', str(out)]) == 0
    written = yaml.safe_load(out.read_text())
    assert len(parse_obstacles(str(out))) == 1 and len(parse_objects(str(out))) == 2
    shipped = yaml.safe_load(open(os.path.join(PACKAGE, 'config', 'pick_world.yaml')).read())
    assert written == shipped == world(setup, 2, 0)         # pick.launch's default world is this command's


def test_clicks_that_cannot_be_picks_say_why():
    setup = setup_of(ROBOTIQ)
    made = world(setup, 1, 0)
    picking, arm = picking_in(setup, made)
    cube = np.array(made['objects'][0]['position'])
    assert picking.choose(cube + [0.01, 0, 0.02], {'cube': cube}) == 'cube'
    with pytest.raises(PickError, match='no object within 0.08 m .* the nearest, cube, is 0.300 m away'):
        picking.choose(cube + [0, 0.3, 0], {'cube': cube})
    with pytest.raises(PickError, match='no objects to pick'):
        picking.choose(cube, {})
    tall = PickPlace(setup, obstacles=made['obstacles'], objects=[     # a click on a 16 cm can's top: 8 cm over its
        {'cylinder': [0.025, 0.16], 'position': [0.5, 0.0, 0.0], 'name': 'can'}])    # middle, as rviz gives it
    assert tall.choose(cube + [0, 0, 0.085], {'can': cube, 'cube_2': cube + [0, 0.09, 0]}) == 'can'
    with pytest.raises(PickError, match='the nearest, can, is 0.090 m away'):
        tall.choose(cube + [0, 0, 0.17], {'can': cube})
    top = setup.space.table_top                 # 10 cm from another object is free: the can's 5 cm width counts
    assert tall.place_of([cube[0], cube[1], top], {'cube_2': cube + [0.1, 0, 0]}, 'can')[2] == pytest.approx(top + 0.08)
    with pytest.raises(PickError, match=r'is taken: cube_2 stands 0.070 m from it'):
        tall.place_of([cube[0], cube[1], top], {'cube_2': cube + [0.07, 0, 0]}, 'can')
    top = setup.space.table_top
    with pytest.raises(PickError, match=r'\+0.100 m from the table\'s top .* click on the table'):
        picking.place_of([cube[0], cube[1], top + 0.1])
    with pytest.raises(PickError, match='outside the workspace'):
        picking.place_of([cube[0] + 1.0, cube[1], top])
    with pytest.raises(PickError, match=r'is taken: cube_2 stands 0.030 m from it'):
        picking.place_of([cube[0], cube[1], top], {'cube_2': cube + [0.03, 0, 0]})
    with pytest.raises(PickError, match='lies outside the workspace'):
        picking.start('cube', cube + [0, 0, -0.5], picking.place_of([cube[0], cube[1], top]), 0.0)
    assert not picking.phase                # nothing started


def test_a_policy_that_answers_nan_ends_the_pick_and_the_arm_holds():
    setup = setup_of(ROBOTIQ)
    made = world(setup, 1, 0)
    picking, arm = picking_in(setup, made, policy=lambda x: np.full((len(x), 4), np.nan))
    run = run_in_physics(picking, arm, 'cube', [*setup.space.centre[:2], setup.space.table_top])
    assert run.outcome.startswith('not placed: the policy answered [nan'), run
    assert not picking.phase
    np.testing.assert_allclose(arm.object_poses()['cube'][:3, 3], made['objects'][0]['position'], atol=2e-3)


def test_a_can_and_a_brick_are_set_down_at_their_own_height():
    """Objects of other shapes (arm_sim's objects: cylinders, boxes of any size) are set down where clicked, their
    middle at their own half height over the table, not the task's cube's."""
    setup = setup_of(ROBOTIQ)
    c, top = setup.space.centre, setup.space.table_top
    for spec, half in (({'cylinder': [0.02, 0.06], 'name': 'can'}, 0.03),
                       ({'box': [0.03, 0.05, 0.05], 'name': 'brick'}, 0.025)):
        made = {'obstacles': [setup.table()], 'objects': [dict(spec, position=[c[0] + 0.05, c[1] - 0.05, top + half])],
                'home': dict(zip(setup.arm.joints, setup.space.ready))}
        picking, arm = picking_in(setup, made, objects=made['objects'])
        assert picking.half_height(spec['name']) == pytest.approx(half)
        run = run_in_physics(picking, arm, spec['name'], [c[0] - 0.1, c[1] + 0.1, top])
        assert run.outcome.startswith(f'placed {spec["name"]}'), run
        np.testing.assert_allclose(arm.object_poses()[spec['name']][:3, 3], [c[0] - 0.1, c[1] + 0.1, top + half],
                                   atol=0.015)


def test_a_can_taller_than_the_fingers_are_deep_is_gripped_below_the_palm():
    """An object that stands taller than the hand's fingers are deep (the Robotiq's palm 6 cm above its grip point)
    is gripped above its middle, its top below the palm, and placed: gripped at its middle, the palm stood on the
    top of a 16 cm can and the fingers, closing on it there, toppled it (the Gen3's 2F-85 stalled on a 10 cm can)."""
    setup = setup_of(ROBOTIQ)
    c, top = setup.space.centre, setup.space.table_top
    can = {'cylinder': [0.025, 0.16], 'name': 'can', 'position': [c[0] + 0.05, c[1] - 0.05, top + 0.08]}
    made = {'obstacles': [setup.table()], 'objects': [can], 'home': dict(zip(setup.arm.joints, setup.space.ready))}
    picking, arm = picking_in(setup, made, objects=made['objects'])
    assert picking.grasp_above('cube') == 0.0
    assert picking.grasp_above('can') == pytest.approx(0.08 + 0.01 - setup.space.grip.depth)
    assert 0.02 < picking.grasp_above('can') < 0.08
    run = run_in_physics(picking, arm, 'can', [c[0] - 0.1, c[1] + 0.1, top])
    assert run.outcome.startswith('placed can'), run
    np.testing.assert_allclose(arm.object_poses()['can'][:3, 3], [c[0] - 0.1, c[1] + 0.1, top + 0.08], atol=0.015)
    assert run.fastest < 1.0 and run.within_limits, run


def test_a_bar_along_the_fingers_is_gripped_across_its_narrow_side():
    """A box wider across the fingers than they open, near enough (a 3x8x3 cm bar lying along the Panda's closing
    axis; its fingers open 4 cm each), is gripped across its narrow side, the gripper turned about the vertical by the
    least angle (90 degrees here), and placed; unturned, the fingers closed on its ends and the pick stalled. A cube's
    grip is not turned."""
    import math
    setup = setup_of(PANDA)
    assert setup.space.grip.opening == pytest.approx(0.08, abs=0.001)        # the URDF's two 0.04 m finger slides
    c, top = setup.space.centre, setup.space.table_top
    closing = setup.space.rotation @ setup.space.grip.closing
    yaw = math.atan2(closing[1], closing[0]) - math.pi / 2         # the bar's long side (its y) along the closing axis
    bar = {'box': [0.03, 0.08, 0.03], 'rpy': [0, 0, yaw], 'name': 'bar', 'position': [c[0] + 0.05, c[1] - 0.05,
                                                                                       top + 0.015]}
    made = {'obstacles': [setup.table()], 'objects': [bar], 'home': dict(zip(setup.arm.joints, setup.space.ready))}
    picking, arm = picking_in(setup, made, objects=made['objects'])
    pose = arm.object_poses()['bar']
    held = picking.grip_rotation('bar', pose)
    assert abs((held @ setup.space.grip.closing) @ pose[:3, 0]) == pytest.approx(1.0, abs=1e-5)    # across its 3 cm
    down = setup.space.rotation @ setup.space.grip.approach                   # turned about the vertical: still down
    assert (held @ setup.space.grip.approach)[2] == pytest.approx(down[2], abs=1e-12) and down[2] < -0.999
    assert abs(np.trace(held.T @ setup.space.rotation) - 1.0) < 1e-9                         # a quarter turn
    np.testing.assert_allclose(picking.grip_rotation('cube', pose), setup.space.rotation)
    run = run_in_physics(picking, arm, 'bar', [c[0] - 0.1, c[1] + 0.1, top])
    assert run.outcome.startswith('placed bar'), run
    assert run.fastest < 1.0 and run.within_limits, run

def test_an_object_that_sways_as_it_is_set_down_is_not_carried_up_again():
    """The policy is given the place CARRY above it until the object is over it (within a centimetre in the plane),
    then the place itself, kept while the object sways within 4 cm (the Gen3 swayed a centimetre as it lowered a
    brick, was sent back up, and stalled over the place); farther, the place above it again."""
    setup = setup_of(PANDA)
    goals = []

    def policy(flat):
        goals.append(flat[0, 3:6].copy())
        return np.zeros((len(flat), 4))
    picking = PickPlace(setup, obstacles=[setup.table()], policy=policy)
    place = picking.place_of([*setup.space.centre[:2], setup.space.table_top])
    q, finger, pose = picking.ready, float(setup.grip_open[0]), np.eye(4)
    pose[:3, 3] = place + [0.05, 0.0, 0.0]
    picking.start('cube', pose[:3, 3], place, 0.0)
    picking.step(0.0, q, finger, pose)
    assert picking.phase == 'task'
    offsets = (0.03, 0.005, 0.03, 0.035, 0.05, 0.03)
    for k, off in enumerate(offsets):
        pose[:3, 3] = place + [off, 0.0, 0.06]
        picking.step(0.04 * (k + 1), q, finger, pose)
    assert picking.phase == 'task'
    np.testing.assert_allclose(np.array(goals)[:, 2] - place[2], [CARRY, 0.0, 0.0, 0.0, CARRY, CARRY])


def test_a_ready_configuration_that_touches_gives_way_to_the_nearest_clear_one(monkeypatch):
    """Where the layer's body finds the task's ready configuration touching (the Fetch's upper arm by its head), the
    other configurations with the gripper there are compared and the nearest the task's taken, which the policy
    learned from (the first found had the Fetch's wrist roll 0.4 rad from the end of its range, and its picks
    wandered off)."""
    from robot_ai.motion.body import CollisionModel
    from robot_ai.physics import workspace
    setup = setup_of(ROBOTIQ)
    ready = setup.space.ready
    found = iter([ready + 1.0, ready - 0.7, ready + 0.2, ready + 1.5] * 20)
    monkeypatch.setattr(workspace, 'ready_pose', lambda *args: (np.clip(next(found), setup.arm.lower,
                                                                        setup.arm.upper), 0.0, 0.0))
    monkeypatch.setattr(CollisionModel, 'in_collision',      # within the layer's margin only (reach's home check
                        lambda self, q, padding=0.0:            # is without: the task's ready is its home)
                        np.all(np.isclose(np.atleast_2d(q), ready), axis=1) & (padding > 0))
    monkeypatch.setattr(CollisionModel, 'contacts',
                        lambda self, q, padding=0.0: ['forearm_link - table'] if padding > 0 else [])
    picking = PickPlace(setup, obstacles=[setup.table()])
    np.testing.assert_allclose(picking.ready, np.clip(ready + 0.2, setup.arm.lower, setup.arm.upper))
    assert 'touches (forearm_link - table)' in picking.ready_note and 'the nearest it of 8 found' in picking.ready_note
