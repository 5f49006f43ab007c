"""robot_ai/Push-v0 and robot_ai/PickAndPlace-v0 (physics.env) on the Panda with its hand and its real meshes:
gymnasium's env checker, the vector env against SyncVectorEnv bit for bit, HER's vectorised compute_reward, the
layout worked out from the robot (physics.workspace), both tasks solved by the scripted expert, and bad input in one
line. No roscore."""
from __future__ import annotations

import copy
import os
import re

import gymnasium
import numpy as np
import pytest
from gymnasium.error import ResetNeeded
from gymnasium.utils.env_checker import check_env

import robot_ai.physics  # noqa: F401 (registers the envs)
from robot_ai.physics import PhysicsError
from robot_ai.physics.env import ManipulationSetup
from robot_ai.reach.arm import ReachError

from exact_meshes import MESHES, ROBOTS

PANDA = os.path.join(ROBOTS, 'panda.urdf')
IDS = {'push': 'robot_ai/Push-v0', 'pick_and_place': 'robot_ai/PickAndPlace-v0'}


@pytest.fixture(autouse=True)
def meshes(monkeypatch):
    monkeypatch.setenv('ROS_PACKAGE_PATH', os.pathsep.join((MESHES, os.environ.get('ROS_PACKAGE_PATH', ''))))


@pytest.mark.parametrize('task', sorted(IDS))
def test_the_env_checker_passes_and_the_vector_env_equals_sync_vector_env(task):
    env = gymnasium.make(IDS[task], model=PANDA)
    check_env(env.unwrapped, skip_render_check=True)
    vec = gymnasium.make_vec(IDS[task], num_envs=3, model=PANDA)
    assert type(vec.unwrapped).__name__ == 'ManipulationVectorEnv'
    sync = gymnasium.vector.SyncVectorEnv([lambda: gymnasium.make(IDS[task], model=PANDA)] * 3)
    o1, i1 = vec.reset(seed=7)
    o2, i2 = sync.reset(seed=7)
    rng = np.random.default_rng(0)
    for t in range(105):                 # past two 50-step limits: the autoresets too
        a = rng.uniform(-1.2, 1.2, (3, 4)).astype(np.float32)
        if t % 3 == 0:                   # the expert now and then: the cube moves, is gripped, succeeds
            a = vec.unwrapped.setup.expert(o1['observation'], o1['desired_goal']).astype(np.float32)
        (o1, r1, te1, tr1, i1), (o2, r2, _, tr2, i2) = vec.step(a), sync.step(a)
        for key in o1:
            np.testing.assert_array_equal(o1[key], o2[key], err_msg=f'{key} at step {t}')
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(tr1, tr2)
        np.testing.assert_array_equal(i1['is_success'], i2['is_success'])
    assert tr1.dtype == bool and not te1.any()


def test_compute_reward_is_vectorised_as_her_relabels_goals():
    env = gymnasium.make('robot_ai/Push-v0', model=PANDA).unwrapped
    obs, info = env.reset(seed=1)
    achieved = np.array([[0.5, 0.0, 0.2], [0.5, 0.0, 0.2], [0.5, 0.0, 0.2]])
    desired = np.array([[0.5, 0.0, 0.2], [0.5, 0.049, 0.2], [0.5, 0.06, 0.2]])
    np.testing.assert_array_equal(env.compute_reward(achieved, desired, [{}] * 3), [0.0, 0.0, -1.0])
    assert env.compute_reward(achieved[None], desired[None], None).shape == (1, 3)
    obs, reward, _, _, info = env.step(env.action_space.sample())
    assert reward == env.compute_reward(obs['achieved_goal'], obs['desired_goal'], info)
    assert info['is_success'] == (reward == 0.0)
    dense = gymnasium.make('robot_ai/Push-v0', model=PANDA, reward_type='dense').unwrapped
    np.testing.assert_allclose(dense.compute_reward(achieved, desired, None), [0.0, -0.049, -0.06])


def test_the_layout_is_worked_out_from_the_panda_as_panda_gym_writes_it():
    """The grip point 0.100 m below the hand (panda-gym's grasp target: 0.1034), the ready configuration pointing the
    hand down with the fingers closing along y (panda-gym's neutral pose turns the seventh joint by pi/4), the table
    0.2 m under the grip point; at reset the cube rests on the table and the gripper is open."""
    env = gymnasium.make('robot_ai/PickAndPlace-v0', model=PANDA).unwrapped
    space = env.setup.space
    grip = space.grip
    assert grip.offset[2] == pytest.approx(0.1034, abs=0.005) and grip.approach[2] == pytest.approx(1.0)
    np.testing.assert_allclose(space.rotation @ grip.approach, [0, 0, -1], atol=0.02)
    assert abs((space.rotation @ grip.closing)[1]) > 0.999 and grip.open_high
    assert space.ready[-1] == pytest.approx(np.pi / 4, abs=0.02)
    obs, _ = env.reset(seed=0)
    o = obs['observation']
    np.testing.assert_allclose(o[:3], space.centre, atol=1e-3)
    assert o[5] == pytest.approx(space.table_top + 0.02, abs=1e-6) and o[9] == pytest.approx(1.0)
    for _ in range(5):
        obs, *_ = env.step(np.zeros(4))
    assert obs['observation'][5] == pytest.approx(space.table_top + 0.02, abs=1e-3)   # at rest on the table


@pytest.mark.parametrize('task', sorted(IDS))
def test_the_scripted_expert_solves_the_task(task):
    """The expert from the observation alone: over, down, grip, carry (20 of 20 measured); behind, down, push (40 of
    40 measured): the tasks are solvable in 50 steps by this arm's physics and the gripper holds the cube."""
    env = gymnasium.make(IDS[task], model=PANDA)
    solved = 0
    for seed in range(10):
        obs, _ = env.reset(seed=seed)
        for _ in range(50):
            obs, reward, terminated, truncated, info = env.step(
                env.unwrapped.setup.expert(obs['observation'], obs['desired_goal']))
        assert truncated
        solved += info['is_success']
    assert solved >= 9


def _claw_urdf() -> str:
    """The Panda with its hand swapped for a claw of three fingers on independent joints (no mimic), each swinging
    in toward the axis as it closes, so that closed their tips curl up above the grip point (a Kinova's hand does)."""
    with open(PANDA) as f:
        text = f.read()
    parts = [text[:text.index('    <joint name="panda_hand_joint"')],
             '<joint name="palm_joint" type="fixed"><parent link="panda_link8"/><child link="palm"/></joint>'
             '<link name="palm"><inertial><mass value="0.3"/><inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy="0" '
             'ixz="0" iyz="0"/></inertial><collision><origin xyz="0 0 0.015"/><geometry><cylinder radius="0.045" '
             'length="0.03"/></geometry></collision></link>']
    for k in range(3):
        a = 2 * np.pi * k / 3
        parts.append(f'<joint name="finger_{k}_joint" type="revolute"><parent link="palm"/><child link="finger_{k}"/>'
                     f'<origin xyz="{0.04 * np.cos(a):.6f} {0.04 * np.sin(a):.6f} 0.03" rpy="0 0 {a:.6f}"/>'
                     f'<axis xyz="0 -1 0"/><limit lower="0" upper="1.3" effort="10" velocity="2"/></joint>'
                     f'<link name="finger_{k}"><inertial><origin xyz="0 0 0.03"/><mass value="0.05"/><inertia '
                     f'ixx="2e-5" iyy="2e-5" izz="2e-6" ixy="0" ixz="0" iyz="0"/></inertial><collision><origin '
                     f'xyz="0 0 0.03"/><geometry><box size="0.012 0.012 0.06"/></geometry></collision></link>')
    return '\n'.join(parts) + '\n</robot>\n'


def test_a_hand_whose_closed_fingers_curl_up_pushes_with_their_backs():
    """The hand closed is measured with every finger joint closed (each on its own joint here; how deep an object
    goes between the fingers, to the palm's face, with the hand as it is), and a push with it goes as low as its
    curled fingers allow, under the cube's middle: 17 of 20 measured (2 of 20 while the push was
    laid out for the hand as it is open, its fingertips over the cube's top)."""
    from robot_ai.physics.env import TABLE_MARGIN, ManipulationVectorEnv
    from robot_ai.physics.learn import FINAL_SEED, evaluate, expert_policy
    setup = ManipulationSetup('push', urdf=_claw_urdf())
    grip = setup.space.grip
    assert len(setup.gripper) == 3 and grip.closed_beyond < 0 < grip.beyond
    np.testing.assert_allclose(grip.approach, [0, 0, 1], atol=1e-6)     # the palm's face 3 cm down the tip's z
    assert grip.depth == pytest.approx(float(np.linalg.norm(grip.offset)) - 0.03, abs=1e-6)
    assert setup.low[2] == pytest.approx(setup.space.table_top + TABLE_MARGIN + grip.closed_beyond)
    assert setup.sink > 0
    success, _ = evaluate(expert_policy(setup), ManipulationVectorEnv(20, 'push', setup=setup), 20, FINAL_SEED)
    assert success >= 0.7


def test_a_gripper_with_a_placeholder_effort_squeezes_within_the_cap_and_picks():
    """kortex_description's Robotiq 2F-85 gives its finger 1000 N m (9,500 N at the tips): built as it stands the
    servo flung the cube up out of the fingers (the expert picked 2 of 100). The package's UR5 with its Robotiq, the
    finger's effort made 1000 as there: held to 250 N at the tips and said, and the expert picks (none of these 20
    without the cap); the package's own 10 N m (95 N) is left as it is."""
    from robot_ai.physics.env import ManipulationVectorEnv
    from robot_ai.physics.learn import FINAL_SEED, evaluate, expert_policy
    from robot_ai.physics.model import GRIP_FORCE
    from robot_ai.reach.model import load_model
    own = ManipulationSetup('pick_and_place', model=UR5_ROBOTIQ)
    k = own.physics.actuated.index('finger_joint')
    assert own.physics.model.actuator_forcerange[k, 1] == 10.0
    assert not any('capped' in n for n in own.physics.notes)
    text = load_model(UR5_ROBOTIQ).urdf.replace('effort="10"', 'effort="1000"')
    setup = ManipulationSetup('pick_and_place', urdf=text)
    most = setup.physics.model.actuator_forcerange[k, 1]
    assert 10.0 < most < 1000.0 and 0.08 < most / GRIP_FORCE < 0.13       # the finger's lever: about 0.1 m
    assert any(n.startswith(f'gripper effort limits past {GRIP_FORCE:g} N at the fingertips, capped there: '
                            'finger_joint: 1000 -> ') for n in setup.physics.notes), setup.physics.notes
    env = ManipulationVectorEnv(20, 'pick_and_place', setup=setup)
    success, _ = evaluate(expert_policy(setup), env, 20, FINAL_SEED)
    assert success >= 0.9


def test_a_long_gripper_holds_the_cube_at_its_tips_and_carries_it():
    """The Robotiq 2F-140 holds the cube 6 cm below the grip point: with the fingers' reach (ManipulationSetup passes
    the arm's) the expert carries it, the cube's own position to the goal; without it the cube is taken for not held
    and let go (Gen3 + 2F-140: 41 % of 100 picks, 100 % with it)."""
    from robot_ai.physics.expert import expert_actions
    obs = np.zeros(23)
    obs[0:3], obs[3:6], obs[9] = [0.4, 0.0, 0.2], [0.405, 0.0, 0.135], 0.4      # gripping, the fingers stopped
    obs[6:9] = obs[3:6] - obs[0:3]
    goal = np.array([0.5, 0.1, 0.3])
    carried = expert_actions(obs, goal, 'pick_and_place', reach=0.062)
    assert carried[3] == -1.0 and np.all(carried[:3] > 0)          # closed, toward the goal
    np.testing.assert_allclose(carried[:3], np.clip(10.0 * (goal - obs[3:6]), -1, 1))   # the cube's error
    dropped = expert_actions(obs, goal, 'pick_and_place')
    assert dropped[3] == 1.0                                        # opened: not held


def test_a_wide_slow_gripper_opens_no_wider_than_the_cube_needs():
    """The Panda's fingers made to open 13 cm at 35 mm/s (a Gen3 lite's opens 12.6 cm and took half the episode to
    close from wide open: its expert picked 64 % of 400): the fingers' gap is measured at every tenth of the opening
    (two fingers on slides: twice the joint), the expert opens them only 1.5 cm wider than the cube on either side,
    and picks where, opened wide, it runs out of time (20 of 20 measured against 9 of 20). The Panda as it is closes
    on the cube in 0.1 s: wide open, as before."""
    from robot_ai.physics.env import AJAR, ManipulationVectorEnv
    from robot_ai.physics.learn import FINAL_SEED, evaluate, expert_policy
    fast = ManipulationSetup('pick_and_place', model=PANDA)
    assert not fast.slow_gripper and fast.ajar == 1.0
    with open(PANDA) as f:
        text = f.read().replace('upper="0.04" velocity="0.2"', 'upper="0.065" velocity="0.035"')
    setup = ManipulationSetup('pick_and_place', urdf=text)
    grip = setup.space.grip
    assert setup.slow_gripper
    np.testing.assert_allclose(grip.gaps(setup.object_size / 2), 2 * 0.065 * np.linspace(0, 1, 11), atol=1e-3)
    assert setup.ajar == pytest.approx((setup.object_size + 2 * AJAR) / grip.opening, abs=0.01)
    env = ManipulationVectorEnv(20, 'pick_and_place', setup=setup)
    ajar, _ = evaluate(expert_policy(setup), env, 20, FINAL_SEED)
    setup.ajar = 1.0
    wide, _ = evaluate(expert_policy(setup), env, 20, FINAL_SEED)
    assert ajar >= 0.85 and wide <= 0.7


def test_the_expert_opens_the_gripper_ajar_and_does_not_take_it_for_holding_the_cube():
    """Open to ajar is the action's opening 2 ajar - 1; fingers stopped there beside the cube hold nothing (the
    arm goes down and closes), fingers stopped well short of it hold the cube (carried); a long gripper comes over
    the cube high enough that its fingertips clear it (the 2F-140's swept it aside from 6 cm over its middle)."""
    from robot_ai.physics.expert import TIPS_ABOVE, expert_actions
    obs = np.zeros(23)
    obs[0:3], obs[3:6], obs[9] = [0.4, 0.0, 0.2], [0.4, 0.0, 0.02], 0.6     # high over the cube, stopped at 0.6
    obs[6:9] = obs[3:6] - obs[0:3]
    goal = np.array([0.5, 0.1, 0.3])
    over = expert_actions(obs, goal, 'pick_and_place', ajar=0.6)
    assert over[3] == pytest.approx(0.2) and over[2] < 0               # ajar, and down to the cube
    obs[2], obs[8] = 0.02, 0.0                                        # around it, stopped ajar: not held, closes
    assert expert_actions(obs, goal, 'pick_and_place', ajar=0.6)[3] == -1.0
    obs[9] = 0.45                                                     # stopped on it: held, carried up
    held = expert_actions(obs, goal, 'pick_and_place', ajar=0.6)
    assert held[3] == -1.0 and held[2] > 0
    obs[0:3], obs[9] = [0.38, 0.0, 0.1], 1.0            # 2 cm aside, 8 cm over the middle: over it first
    obs[6:9] = obs[3:6] - obs[0:3]
    assert 0.02 + 0.062 + TIPS_ABOVE > 0.1 > 0.02 + 0.06
    assert expert_actions(obs, goal, 'pick_and_place', reach=0.062)[2] > 0      # the long fingers: up
    assert expert_actions(obs, goal, 'pick_and_place', reach=0.01)[2] < 0       # short ones: down


def test_a_tip_among_the_fingers_approaches_from_the_wrist():
    """Interbotix's arms end in fingers_link, among their fingers (their middle 1 mm behind it): the approach seen
    from the tip pointed backwards and no ready configuration was found (vx300s). The Panda's fingers hung from a
    frame at their middle: the approach is the hand's z, from the wrist, the grip point where the Panda's own is, and
    the expert picks as with the Panda's own hand (10 of 10 measured)."""
    from robot_ai.physics.env import ManipulationVectorEnv
    from robot_ai.physics.learn import FINAL_SEED, evaluate, expert_policy
    with open(PANDA) as f:
        text = f.read()
    text = text.replace('<parent link="panda_hand" />\n        <child link="panda_leftfinger" />\n'
                        '        <origin rpy="0 0 0" xyz="0 0 0.0584" />',
                        '<parent link="panda_fingers" />\n        <child link="panda_leftfinger" />\n'
                        '        <origin rpy="0 0 0" xyz="0 0 -0.0336" />')
    text = text.replace('<parent link="panda_hand" />\n        <child link="panda_rightfinger" />\n'
                        '        <origin rpy="0 0 0" xyz="0 0 0.0584" />',
                        '<parent link="panda_fingers" />\n        <child link="panda_rightfinger" />\n'
                        '        <origin rpy="0 0 0" xyz="0 0 -0.0336" />')
    assert text.count('"panda_fingers"') == 2
    text = text.replace('</robot>', '<link name="panda_fingers"/><joint name="panda_fingers_joint" type="fixed">'
                        '<parent link="panda_hand"/><child link="panda_fingers"/><origin xyz="0 0 0.092"/></joint>'
                        '</robot>')
    own = ManipulationSetup('pick_and_place', model=PANDA).space.grip
    setup = ManipulationSetup('pick_and_place', urdf=text, tip='panda_fingers')
    grip = setup.space.grip
    np.testing.assert_allclose(grip.approach, [0, 0, 1], atol=1e-6)
    np.testing.assert_allclose(grip.offset, own.offset - [0, 0, 0.092], atol=1e-6)
    success, _ = evaluate(expert_policy(setup), ManipulationVectorEnv(10, 'pick_and_place', setup=setup), 10,
                          FINAL_SEED)
    assert success >= 0.9


def test_an_arm_that_cannot_reach_the_workspace_says_so():
    """The Panda's first, third and fifth joints held within 0.05 rad of their middle (the arm moves in its plane):
    pointing down, the gripper reaches none of the workspace's corners (0.17 m either side) and the setup says so, as
    a warning (Interbotix's px100, 30 cm long,
    picked 1 of 100 without a word); the Panda as it is reaches all four and says nothing."""
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        assert ManipulationSetup('push', model=PANDA).notes == ()
    with open(PANDA) as f:
        text = f.read().replace('lower="-2.9671" upper="2.9671"', 'lower="-0.05" upper="0.05"', 3)
    with pytest.warns(UserWarning, match=r"panda: pointing down, the gripper reaches 0 of the workspace's 4 corners"):
        setup = ManipulationSetup('push', urdf=text)
    assert setup.space.note.endswith('out of its reach')


def test_a_hand_whose_own_geometry_stands_between_its_fingers_says_so(tmp_path, capsys):
    """franka_description's Panda (hand:=true, not gazebo:=true) gives its hand a link of self-collision capsules, one
    of them between the fingers 5 cm past the grip point: the expert picked none of 100 without a word. The same
    capsule on the package's Panda: the setup names the link, as a warning; the command line as a note."""
    from robot_ai.physics.__main__ import main
    with open(PANDA) as f:
        text = f.read().replace('</robot>', (
            '<link name="panda_hand_sc"><collision><origin xyz="0 0 0.10" rpy="1.5708 0 0"/><geometry><cylinder '
            'radius="0.02" length="0.1"/></geometry></collision></link><joint name="panda_hand_sc_joint" '
            'type="fixed"><parent link="panda_hand"/><child link="panda_hand_sc"/></joint></robot>'))
    says = "panda: the hand's own geometry (panda_hand_sc) stands between the open fingers past the grip point"
    with pytest.warns(UserWarning, match=re.escape(says)):
        setup = ManipulationSetup('pick_and_place', urdf=text)
    assert setup.space.grip.between == ('panda_hand_sc',) and len(setup.notes) == 1     # pick_place logs them
    path = tmp_path / 'panda_sc.urdf'
    path.write_text(text)
    assert main(['train', '--task', 'push', '--model', str(path), '--minutes', '0.01', '--worlds', '2',
                 '--output-dir', str(tmp_path)]) == 0
    assert f'note: {says}' in capsys.readouterr().err


def test_push_holds_the_gripper_closed_and_bad_input_is_one_line():
    env = gymnasium.make('robot_ai/Push-v0', model=PANDA)
    with pytest.raises(ResetNeeded):
        env.step(np.zeros(4))
    obs, _ = env.reset(seed=0)
    assert obs['observation'][9] == pytest.approx(0.0)
    for _ in range(5):
        obs, *_ = env.step(np.array([0, 0, 0, 1.0]))            # "open": Push-v0 keeps it closed
    assert obs['observation'][9] < 0.01
    for bad in ([0, 0, float('nan'), 0], [0, 0, 0]):
        with pytest.raises(ValueError, match='an action is 4 finite numbers') as e:
            env.step(np.array(bad))
        assert '\n' not in str(e.value)
    with pytest.raises(ReachError, match='give model= an arm with a gripper'):
        ManipulationSetup('push')
    with pytest.raises(PhysicsError, match='the arm has no gripper'):
        ManipulationSetup('push', model=os.path.join(ROBOTS, 'ur5.urdf'))
    with pytest.raises(ValueError, match="task must be one of"):
        ManipulationSetup('lift', model=PANDA)


UR5_ROBOTIQ = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', '..', 'urdf',
                           'ur5_robotiq_2f85.urdf.xacro')


@pytest.mark.parametrize('task', sorted(IDS))
def test_a_ur5_with_a_robotiq_2f85_pushes_picks_and_places_its_hinged_fingers_open_the_other_way(task):
    """The package's xacro joining its UR5 and a Robotiq 2F-85 (a knuckle that closes toward its upper limit, five
    joints mimicking it): the layout finds that it opens toward 0 and closes along y, the env checker passes, and
    the expert pushes (39 of 40 measured) and picks and places (18 of 20) with it."""
    env = gymnasium.make(IDS[task], model=UR5_ROBOTIQ)
    check_env(env.unwrapped, skip_render_check=True)
    setup = env.unwrapped.setup
    assert setup.gripper == ('finger_joint',) and not setup.space.grip.open_high
    assert abs((setup.space.rotation @ setup.space.grip.closing)[1]) > 0.999
    obs, _ = env.reset(seed=0)
    assert obs['observation'][9] == pytest.approx(1.0 if task == 'pick_and_place' else 0.0)   # the knuckle at 0: open
    solved = 0
    for seed in range(10):
        obs, _ = env.reset(seed=seed)
        for _ in range(50):
            obs, _, _, _, info = env.step(setup.expert(obs['observation'], obs['desired_goal']))
        solved += info['is_success']
    assert solved >= 8


def test_a_two_armed_robot_grips_with_the_hand_of_its_arm():
    """The PR2 (two grippers; its default tip, r_gripper_tool_frame, hangs beside the fingers): the arm's tip moves
    up to the palm that carries them, and the gripper is that hand's, not the other one's."""
    setup = ManipulationSetup('push', model=os.path.join(ROBOTS, 'pr2.urdf'))
    assert setup.arm.tip == 'r_gripper_palm_link' and all(n.startswith('r_gripper') for n in setup.gripper)
    left = ManipulationSetup('push', model=os.path.join(ROBOTS, 'pr2.urdf'), tip='l_wrist_roll_link')
    assert left.gripper and all(n.startswith('l_gripper') for n in left.gripper)
    with pytest.raises(PhysicsError, match='no actuated finger joints below r_gripper_tool_frame'):
        ManipulationSetup('push', model=os.path.join(ROBOTS, 'pr2.urdf'), tip='r_gripper_tool_frame')


def test_a_reset_mask_resets_those_worlds_only_as_sync_vector_env_does():
    vec = gymnasium.make_vec('robot_ai/Push-v0', num_envs=3, model=PANDA)
    sync = gymnasium.vector.SyncVectorEnv([lambda: gymnasium.make('robot_ai/Push-v0', model=PANDA)] * 3)
    vec.reset(seed=3)
    sync.reset(seed=3)
    a = np.full((3, 4), 0.5, dtype=np.float32)
    vec.step(a)
    sync.step(a)
    mask = np.array([False, True, False])
    (o1, i1), (o2, _) = vec.reset(seed=[None, 9, None], options={"reset_mask": mask}), \
        sync.reset(seed=[None, 9, None], options={'reset_mask': mask})
    for key in o1:
        np.testing.assert_array_equal(o1[key], o2[key])
    np.testing.assert_array_equal(i1['_is_success'], mask)
    with pytest.raises(ValueError, match='length must match num_envs=3'):
        vec.reset(seed=[1, 2])


def test_the_observation_is_of_the_joints_as_they_stand_and_the_cube_spins_in_the_root_frame():
    """After a step the grip point is where the kinematics puts it for the joints reported (MuJoCo's bodies lag its
    joints by a step after mj_step: 1 mm at speed), the cube's velocity is MuJoCo's own (mj_objectVelocity, in the
    world frame), and the ready configuration is the same in every process (rounded, whatever BLAS's last bits)."""
    import mujoco
    env = gymnasium.make('robot_ai/PickAndPlace-v0', model=PANDA).unwrapped
    setup = env.setup
    np.testing.assert_array_equal(np.round(setup.space.ready, 9), setup.space.ready)
    obs, _ = env.reset(seed=4)
    moved = 0.0
    for _ in range(25):
        obs, *_ = env.step(setup.expert(obs['observation'][None], obs['desired_goal'][None])[0])
        q = env.data.qpos[setup.q_address]
        np.testing.assert_allclose(obs['observation'][:3], setup.grip_points(q[:, None])[0][:, 0], atol=1e-9)
        res, now = np.zeros(6), copy.copy(env.data)
        mujoco.mj_forward(setup.physics.model, now)     # mj_step leaves its velocities a step behind too
        mujoco.mj_objectVelocity(setup.physics.model, now, mujoco.mjtObj.mjOBJ_BODY, setup.object_body, res, 0)
        np.testing.assert_allclose(obs['observation'][13:19], [*res[3:], *res[:3]], atol=1e-12)
        moved = max(moved, float(np.linalg.norm(obs['observation'][13:19])))
    assert moved > 0.05                  # the cube was carried: its velocity was checked in motion


def test_two_processes_build_the_same_world_and_observe_the_same_episode():
    """The same seed and actions give the same observations, bit for bit, in two processes (an env over ROS and its
    sim are two): the layout and the servos' gains no longer carry BLAS's last bits, which follow memory alignment."""
    import subprocess
    import sys
    code = ('import hashlib, numpy as np, gymnasium, robot_ai.physics\n'
            'from robot_ai.physics.model import model_digest\n'
            f'env = gymnasium.make("robot_ai/PickAndPlace-v0", model={PANDA!r}).unwrapped\n'
            'h = hashlib.sha256(model_digest(env.setup.physics.model).encode())\n'
            'obs, _ = env.reset(seed=3)\n'
            'rng = np.random.default_rng(0)\n'
            'for _ in range(30):\n'
            '    h.update(obs["observation"].tobytes())\n'
            '    obs, *_ = env.step(rng.uniform(-1, 1, 4))\n'
            'print(h.hexdigest())\n')
    env = dict(os.environ)
    digests = set()
    for pad in ('', 'x' * 4099, 'x' * 12345):    # the environment's size: the process's memory laid out otherwise
        env['ROBOT_AI_TEST_PAD'] = pad
        run = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=300, env=env)
        assert run.returncode == 0, run.stderr[-2000:]
        digests.add(run.stdout.strip())
    assert len(digests) == 1
