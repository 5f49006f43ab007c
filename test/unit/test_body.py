"""robot_ai.motion.body: the arm's body as spheres fitted to its URDF <collision> geometry, the link pairs
checked, obstacles; every sphere check against an exact mesh check (python-fcl through trimesh) on 10,000 random
configurations of the reference arms that carry their geometry. No rospy."""
from __future__ import annotations

import os

import numpy as np
import pytest
import trimesh

from robot_ai.motion import body as body_module
from robot_ai.motion.body import BodyError, CollisionModel, fit_spheres, parse_obstacles
from robot_ai.reach.arm import Arm, ReachError
from robot_ai.reach.model import load_model

from exact_meshes import MESHES, Exact

HERE = os.path.dirname(os.path.realpath(__file__))
ROBOTS = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', '..', '..', 'shared', 'robots')
WORLD = [{'box': [2.0, 2.0, 0.05], 'position': [0, 0, -0.03], 'name': 'table'},
         {'box': [0.2, 0.3, 0.4], 'position': [0.45, 0.1, 0.3], 'rpy': [0, 0, 0.5], 'name': 'box 1'},
         {'box': [0.1, 0.1, 0.6], 'position': [-0.3, -0.4, 0.5], 'name': 'box 2'}]


def test_a_points_distance_to_a_mesh_is_trimeshs_own():
    """body.mesh_distance measures only the triangles that can be nearest: the same distances as trimesh's pass over
    every triangle, for points near and far, outside and inside, on a real collision mesh (the UR5's forearm, the
    Panda's hand) and on a fine sphere of 5,120 triangles."""
    rng = np.random.default_rng(0)
    meshes = [trimesh.load(os.path.join(MESHES, *path.split('/')), force='mesh') for path in (
        'ur_description/meshes/ur5/collision/forearm.stl',
        'moveit_resources_panda_description/meshes/collision/hand.stl')]
    for mesh in meshes + [trimesh.creation.icosphere(subdivisions=4, radius=0.1)]:
        low, high = mesh.bounds
        points = low + rng.uniform(-0.5, 1.5, (400, 3)) * (high - low)
        points[:50] = mesh.vertices[rng.integers(0, len(mesh.vertices), 50)]          # on the surface
        expected = trimesh.proximity.closest_point_naive(mesh, points)[1]
        np.testing.assert_array_equal(body_module.mesh_distance(mesh, points), expected)
        assert np.all(expected[:50] < 1e-9) and expected.max() > 0.01


def test_obstacles_from_a_list_yaml_text_or_a_file(tmp_path):
    text = 'obstacles:\n  - {box: [1, 1, 0.05], position: [0, 0, -0.03]}\n  - {sphere: 0.1, position: [0.4, 0, 0.5]}\n'
    path = tmp_path / 'world.yaml'
    path.write_text(text)
    for given in (text, str(path), parse_obstacles(text) and [dict(box=[1, 1, 0.05], position=[0, 0, -0.03]),
                                                               dict(sphere=0.1, position=[0.4, 0, 0.5])]):
        table, ball = parse_obstacles(given)
        assert (table.kind, table.size, ball.kind, ball.size) == ('box', (1.0, 1.0, 0.05), 'sphere', (0.1,))
        np.testing.assert_array_equal(ball.pose[:3, 3], [0.4, 0, 0.5])
        assert table.spec == {'position': [0.0, 0.0, -0.03], 'box': [1.0, 1.0, 0.05], 'rpy': [0.0, 0.0, 0.0],
                              'name': 'obstacle 0 (box)'}
    assert parse_obstacles(None) == () and parse_obstacles([]) == ()


@pytest.mark.parametrize('bad, says', [
    ([{'box': [1, 1]}], 'box must be 3 finite numbers'), ([{'box': [1, 1, 1], 'sphere': 1}], 'give one of'),
    ([{'sphere': -1}], 'must be positive'), ([{'sphere': 0.1, 'rpy': [0, 0, 0]}], 'a sphere has no rpy'),
    ([{'sphere': 0.1, 'colour': 'red'}], 'unknown keys'), ({'sphere': 0.1}, 'must be a list'),
    ([{'box': [1, 1, float('nan')]}], 'finite'), ('/no/such/world.yaml', 'cannot read'), ('- [unclosed', 'not YAML')])
def test_a_bad_world_is_one_line(bad, says):
    """A BodyError of one line; a reach task given it says the same line as its own ReachError."""
    from robot_ai.reach.env import ReachSetup
    with pytest.raises(BodyError, match=says) as e:
        parse_obstacles(bad)
    assert '\n' not in str(e.value)
    with pytest.raises(ReachError, match=says) as r:
        ReachSetup(os.path.join(ROBOTS, 'kuka_lwr_arm.urdf'), obstacles=bad)
    assert str(r.value) == str(e.value)


@pytest.mark.parametrize('shape', [trimesh.creation.box(extents=[0.1, 0.1, 0.4]),
                                   trimesh.creation.cylinder(radius=0.07, height=0.208, sections=24),
                                   trimesh.creation.box(extents=[0.5, 0.3, 0.02]),
                                   trimesh.creation.capsule(height=0.3, radius=0.05)])
def test_the_spheres_cover_the_shape(shape):
    centres, radii = fit_spheres(shape, np.random.default_rng(0))
    assert 1 <= len(radii) <= 8
    points, _ = trimesh.sample.sample_surface(shape, 5000, seed=1)
    covered = np.any(np.linalg.norm(points[:, None] - centres[None], axis=2) <= radii[None] + 1e-6, axis=1)
    assert covered.mean() > 0.995, covered.mean()     # the fit's points are a sample too: the rest within a hair
    gap = np.min(np.linalg.norm(points[:, None] - centres[None], axis=2) - radii[None], axis=1).max()
    assert gap < 0.01 * np.ptp(shape.vertices, axis=0).max()


@pytest.mark.parametrize('robot, tip', [('kuka_lwr_arm.urdf', None), ('pr2.urdf', 'r_gripper_tool_frame'),
                                        ('ur5.urdf', None), ('panda.urdf', 'panda_hand')])
def test_every_sphere_check_agrees_with_the_exact_meshes_on_10000_configurations(robot, tip, monkeypatch):
    """No contact of the meshes is missed by the spheres, and every contact the spheres alone see is one of meshes
    closer than the two links' fitted margins (what the spheres add beyond the geometry). The UR5 and the Panda with
    their real collision meshes (../shared/robots/meshes on ROS_PACKAGE_PATH), every link with a body."""
    monkeypatch.setenv('ROS_PACKAGE_PATH', MESHES)
    model = load_model(os.path.join(ROBOTS, robot))
    arm = Arm(model.tree, tip)
    # the table under the UR5's base, 3 cm below its shoulder's fat spheres (which reach 5 cm below the base)
    world = WORLD if robot != 'ur5.urdf' else [dict(WORLD[0], position=[0, 0, -0.08])] + WORLD[1:]
    body = CollisionModel(model.tree, model.urdf, arm, obstacles=world)
    if robot in ('ur5.urdf', 'panda.urdf'):
        assert body.missing == [] and set(body.links) >= {model.tree.joints[j].child for j in arm.joints}
    q = np.random.default_rng(7).uniform(arm.lower, arm.upper, size=(10000, arm.n))
    spheres = body.in_collision(q)
    exact = Exact(body)
    poses = body.link_poses(q)
    margin = dict(body.margins, **{o.name: 0.0 for o in body.obstacles})
    missed, too_far = [], []
    for n in range(len(q)):
        touching = exact.contacts(poses, n)
        if touching and not spheres[n]:
            missed.append((n, sorted(touching)))
        if spheres[n] and not touching:
            for a, b in (tuple(c.split(' - ')) for c in body.contacts(q[n])):
                distance = exact.distance(poses, n, a, b)
                if distance > margin[a] + margin[b] + 1e-6:
                    too_far.append((n, a, b, distance, margin[a] + margin[b]))
    assert missed == [], missed[:5]
    assert too_far == [], too_far[:5]
    assert spheres.any() and not spheres.all()     # the world is neither empty nor full: the check means something


@pytest.mark.parametrize('robot, tip', [('pr2.urdf', 'r_gripper_tool_frame'), ('ur5.urdf', None),
                                        ('panda.urdf', 'panda_hand')])
def test_the_broad_phase_gives_the_dense_check_s_answers_to_the_bit(robot, tip, monkeypatch):
    """Beyond BROAD_PHASE sphere pairs (the PR2's 12,393), a link pair's spheres are compared only where the links'
    bounds meet: the same answer as every pair compared, on random configurations, along motions and one at a time,
    with and without padding (smaller bodies forced through it too)."""
    monkeypatch.setenv('ROS_PACKAGE_PATH', MESHES)
    model = load_model(os.path.join(ROBOTS, robot))
    arm = Arm(model.tree, tip)
    body = CollisionModel(model.tree, model.urdf, arm, obstacles=WORLD)
    monkeypatch.setattr(body_module, 'BROAD_PHASE', 0)
    rng = np.random.default_rng(11)
    q = rng.uniform(arm.lower, arm.upper, (600, arm.n))
    motions = np.concatenate([np.linspace(a, b, 60) for a, b in zip(q[:10], q[10:20])])
    for batch in (q, motions, q[:1], q[1:2]):
        x, y, z = body._centres_by_coordinate(batch)
        for padding in (0.0, 0.02):
            dense = body._touching(x, y, z, body.pair_a, body.pair_b, padding).any(axis=0)
            np.testing.assert_array_equal(body._self_contacts(x, y, z, padding), dense)
    x, y, z = body._centres_by_coordinate(q)
    assert body._touching(x, y, z, body.pair_a, body.pair_b).any()           # the arm does fold onto itself


def test_the_pairs_excluded_as_moveit_does():
    model = load_model(os.path.join(ROBOTS, 'kuka_lwr_arm.urdf'))
    arm = Arm(model.tree)
    body = CollisionModel(model.tree, model.urdf, arm)
    adjacent = set(body.excluded['adjacent'])
    assert ('lwr_arm_1_link', 'lwr_arm_2_link') in adjacent or ('lwr_arm_2_link', 'lwr_arm_1_link') in adjacent
    assert not body.in_collision(arm.home[None])[0]       # home is never in contact: its contacts are excluded
    assert body.link_pairs, 'a 7-joint arm can fold onto itself'
    assert body.excluded['never'], 'links far apart are never checked'
    for i, j in body.link_pairs:
        assert body.moving[i] or body.moving[j]


def test_a_urdf_with_no_collision_geometry_is_said_to_have_an_empty_body(monkeypatch, caplog):
    """The package's own KUKA file has no <collision> element: its body is empty, said once per process in-process
    as reach_controller says it, never silently."""
    monkeypatch.setattr(body_module, '_WARNED', set())
    kuka = load_model(os.path.join(HERE, '..', '..', 'urdf', 'kuka_lwr_arm.urdf'))
    with caplog.at_level('WARNING', logger='robot_ai.motion.body'):
        body = CollisionModel(kuka.tree, kuka.urdf, Arm(kuka.tree), obstacles=WORLD)
        CollisionModel(kuka.tree, kuka.urdf, Arm(kuka.tree), obstacles=WORLD)
    assert not len(body.radii)
    said = [r.getMessage() for r in caplog.records if 'no collision geometry on its moving links' in r.getMessage()]
    assert len(said) == 1 and said[0].startswith(f'{kuka.tree.name} has no collision geometry'), said
    caplog.clear()
    with caplog.at_level('WARNING', logger='robot_ai.motion.body'):
        CollisionModel(kuka.tree, kuka.urdf, Arm(kuka.tree))
        ur5 = load_model(os.path.join(ROBOTS, 'ur5.urdf'))
        monkeypatch.setenv('ROS_PACKAGE_PATH', MESHES)
        CollisionModel(ur5.tree, ur5.urdf, Arm(ur5.tree))
    assert 'no collision geometry on its moving links' not in caplog.text        # said once; a real body: never


def test_a_link_whose_mesh_is_missing_gets_a_stated_stand_in_never_nothing(monkeypatch, caplog):
    """Without ../shared/robots/meshes the UR5's meshes are not on the machine: every link still has a body (capsules
    along its joint-to-joint segments, radius from its mass), said in one warning per process, and the stand-in
    covers the real mesh's place well enough that a configuration folding the arm into the table is in contact."""
    monkeypatch.setenv('ROS_PACKAGE_PATH', '')
    monkeypatch.setattr(body_module, '_WARNED', set())        # said once per process: this test sees it said
    ur5 = load_model(os.path.join(ROBOTS, 'ur5.urdf'))
    arm = Arm(ur5.tree)
    with caplog.at_level('WARNING', logger='robot_ai.motion.body'):
        body = CollisionModel(ur5.tree, ur5.urdf, arm, obstacles=WORLD)
        again = CollisionModel(ur5.tree, ur5.urdf, arm, obstacles=WORLD)
    assert any('package://ur_description/meshes/ur5/collision/' in m for m in body.missing)
    moving = {ur5.tree.joints[j].child for j in arm.joints}
    assert moving <= set(body.stand_ins) and moving <= set(body.links)
    assert all(f'{link}: ' in caplog.text for link in list(body.stand_ins)[:6])
    assert len([r for r in caplog.records if 'stood in for' in r.getMessage()]) <= 1 and again.stand_ins
    down = arm.home.copy()
    down[1] = 1.2                       # the shoulder lifted down: the upper arm into the table
    assert body.in_collision(down[None])[0] and 'table' in ' '.join(body.contacts(down))
    monkeypatch.setenv('ROS_PACKAGE_PATH', MESHES)
    real = CollisionModel(ur5.tree, ur5.urdf, arm, obstacles=WORLD)
    assert real.missing == [] and real.stand_ins == {}


# ------------------------------------------------------------------------------------------------ in the env
KUKA = os.path.join(ROBOTS, 'kuka_lwr_arm.urdf')


def test_reach_with_a_world_draws_clear_goals_and_starts_and_refuses_a_motion_into_a_box():
    """Goals and random starts are drawn clear of contacts; a step whose motion would touch is not made (the arm
    holds, info['collision']), so the arm is never in contact; without a body nothing changes."""
    from robot_ai.reach.env import ReachEnv
    env = ReachEnv(model=KUKA, obstacles=WORLD, start='random')
    body = env.setup.body
    for seed in range(30):
        obs, info = env.reset(seed=seed)
        assert not body.in_collision(env.joint_positions[None])[0]
    rngs = [np.random.default_rng(seed) for seed in range(300)]
    goals, starts = env.setup.first_states(rngs)
    assert not body.in_collision(goals.T).any() and not body.in_collision(starts.T).any()
    unchecked = ReachEnv(model=KUKA, start='random').setup.first_states([np.random.default_rng(s) for s in range(300)])
    assert body.in_collision(unchecked[0].T).any(), 'the world takes some goals away: the check means something'
    env = ReachEnv(model=KUKA, obstacles=WORLD)
    env.reset(seed=0)
    refused = []
    for _ in range(60):                         # down and out toward box 1 and the table
        before = env.joint_positions
        _, _, _, _, info = env.step(np.array([0.3, 0.0, -1.0], np.float32))
        refused.append(info['collision'])
        assert not body.in_collision(env.joint_positions[None])[0]
        if info['collision']:
            np.testing.assert_array_equal(env.joint_positions, before)
    assert any(refused) and not all(refused)
    plain = ReachEnv(model=KUKA)
    plain.reset(seed=0)
    assert plain.setup.body is None and 'collision' not in plain.step(np.zeros(3, np.float32))[4]


def test_the_vector_env_with_a_world_equals_the_single_envs():
    from robot_ai.reach.env import ReachEnv, ReachVectorEnv
    vector = ReachVectorEnv(3, model=KUKA, obstacles=WORLD, start='random')
    singles = [ReachEnv(model=KUKA, obstacles=WORLD, start='random') for _ in range(3)]
    obs, _ = vector.reset(seed=5)
    for i, env in enumerate(singles):
        np.testing.assert_array_equal(obs['observation'][i], env.reset(seed=5 + i)[0]['observation'])
    rng = np.random.default_rng(1)
    for _ in range(49):
        actions = rng.uniform(-1, 1, (3, 3)).astype(np.float32)
        obs, _, _, _, infos = vector.step(actions)
        for i, env in enumerate(singles):
            single, _, _, _, info = env.step(actions[i])
            np.testing.assert_array_equal(obs['observation'][i], single['observation'])
            assert infos['collision'][i] == info['collision']


def test_a_world_is_checked_by_gymnasium_and_kept_by_a_policy_file(tmp_path):
    from dataclasses import replace

    from gymnasium.utils.env_checker import check_env

    from robot_ai.reach import learn, policy_files
    from robot_ai.reach.env import ReachEnv, ReachSetup
    check_env(ReachEnv(model=KUKA, obstacles=WORLD), skip_render_check=True)
    setup = ReachSetup(model=KUKA, obstacles=WORLD)
    settings = replace(learn.default_settings(setup), iterations=2)
    training = learn.train(dict(model=KUKA, obstacles=WORLD), settings, seed=0, evaluate_episodes=0)
    path = policy_files.save(training, str(tmp_path / 'reach.npz'))
    _, loaded, _ = policy_files.load(path)
    assert [o.spec for o in loaded.obstacles] == [o.spec for o in setup.obstacles]
    assert loaded.body is not None and [o.name for o in loaded.obstacles] == ['table', 'box 1', 'box 2']


def test_a_home_inside_an_obstacle_or_a_full_world_is_one_line():
    from robot_ai.reach.env import ReachSetup
    with pytest.raises(ReachError, match='home is in collision: .* - pillar') as e:
        ReachSetup(model=KUKA, obstacles=[{'box': [0.3, 0.3, 3.0], 'position': [0, 0, 1], 'name': 'pillar'}])
    assert '\n' not in str(e.value)
    with pytest.raises(ReachError, match='collision must be true or false'):
        ReachSetup(model=KUKA, collision='yes')


def test_obstacles_beyond_the_arm_s_reach_are_left_out_of_the_checks_and_said():
    """Issue 55: 5,000 small obstacles far from the arm kept the node silent for minutes and every plan too slow to
    send (the checks run an obstacle at a time). Those no sphere can come within a metre of are left out; the checks
    answer as before."""
    import time
    from robot_ai.reach.env import ReachSetup
    far = [{'sphere': 0.01, 'position': [5 + 0.01 * i, 3, 1]} for i in range(5000)]
    t = time.process_time()
    setup = ReachSetup(os.path.join(ROBOTS, 'kuka_lwr_arm.urdf'), obstacles=WORLD + far)
    near = ReachSetup(os.path.join(ROBOTS, 'kuka_lwr_arm.urdf'), obstacles=WORLD)
    assert setup.body.beyond == 5000 and near.body.beyond == 0
    assert len(setup.body.obstacles) == len(WORLD) and len(setup.obstacles) == len(WORLD) + 5000
    assert 0.5 < setup.body.reach() < 3.0
    q = np.random.default_rng(0).uniform(setup.arm.lower, setup.arm.upper, (500, setup.arm.n))
    np.testing.assert_array_equal(setup.body.in_collision(q), near.body.in_collision(q))
    assert time.process_time() - t < 60        # not minutes
    m = setup.body.moving_spheres                    # a bound: no configuration puts a sphere farther out
    farthest = np.linalg.norm(setup.body.sphere_centres(q)[:, m], axis=-1) + setup.body.radii[m]
    assert farthest.max() <= setup.body.reach()


def test_a_floating_base_robot_has_its_body_below_the_floating_joint():
    """A floating base (a humanoid's pelvis) with a body: the arm's chain starts at the pelvis, its links and the
    pelvis are the body (Unitree H1_2's `train --collision` ended in KeyError: 'pelvis'), and the spheres agree with the
    exact meshes: a configuration folding the arm onto the pelvis is a contact of both, the straight one of neither."""
    path = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', 'urdf', 'floating_body_arm.urdf')
    model = load_model(path)
    arm = Arm(model.tree)
    body = CollisionModel(model.tree, model.urdf, arm)
    assert arm.base == 'pelvis' and set(body.links) == {'pelvis', 'l1', 'l2', 'l3'}
    q = np.array([[0.0, 0.0, 0.0], [0.0, 2.6, 2.6]])        # straight up; folded down onto the pelvis
    exact = Exact(body)
    poses = body.link_poses(q)
    assert [bool(exact.contacts(poses, n)) for n in range(2)] == [False, True]
    assert body.in_collision(q).tolist() == [False, True]
    assert any('pelvis' in pair for pair in body.contacts(q[1]))


def test_a_collada_mesh_is_read_at_its_unit_as_rviz_scales_it(tmp_path):
    """A .dae collision mesh (Kinova's, in their units) read through trimesh and pycollada, scaled by its asset's
    <unit meter=...> as rviz and MoveIt (assimp) scale it; trimesh alone would leave millimetres as metres."""
    box = trimesh.creation.box(extents=[40.0, 20.0, 10.0])         # millimetres
    text = trimesh.exchange.dae.export_collada(box).decode()
    assert '<unit' not in text and '<asset>' in text
    text = text.replace('<asset>', '<asset>\n    <unit meter="0.001" name="millimeter"/>', 1)
    (tmp_path / 'box.dae').write_text(text)
    urdf = (f'<robot name="r"><link name="a"><collision><geometry><mesh filename="{tmp_path}/box.dae"/></geometry>'
            f'</collision></link></robot>')
    shapes, missing = body_module.link_shapes(urdf)
    assert missing == [] and len(shapes['a']) == 1
    np.testing.assert_allclose(sorted(shapes['a'][0].extents), [0.01, 0.02, 0.04], atol=1e-9)
    assert body_module.collada_unit(str(tmp_path / 'box.dae')) == 0.001
