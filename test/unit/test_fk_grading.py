"""robot_ai.grading.fk: configurations within limits, the comparison frame, errors, the report and verdict."""
import math
import os

import numpy as np

from tf import transformations as tft

from fk_helpers import robot_path
from robot_ai.grading.gradebook import grade_of
from robot_ai.grading.fk import Grade, comparison_frame, configurations, rotation_error
from robot_ai.kinematics import KinematicTree

TILTED = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', 'urdf', 'tilted_axis_arm.urdf')


def test_configurations_zero_first_then_within_limits():
    tree = KinematicTree.from_file(robot_path('pr2.urdf'))
    configs = configurations(tree, 30, seed=1)
    assert len(configs) == 30 and set(configs[0].values()) == {0.0}
    assert all(set(c) == set(tree.active_joints) for c in configs)   # mimic joints are left to the nodes
    for name in tree.active_joints:
        j = tree.joints[name]
        values = [c[name] for c in configs[1:]]
        if j.type == 'continuous':
            assert max(abs(v) for v in values) > 2 * math.pi  # over more than one turn
        elif j.lower is not None and j.upper is not None and j.lower < j.upper:
            assert all(j.lower <= v <= j.upper for v in values)
    assert configurations(tree, 30, seed=1) == configs and configurations(tree, 30, seed=2) != configs


def test_comparison_frame():
    tree = KinematicTree.from_file(TILTED)
    assert comparison_frame(tree, {'base', 'shoulder', 'tool'}) == ('base', '')
    # the course's skeleton: every link under a parentless 'world' the URDF does not have, the root unpublished
    frame, note = comparison_frame(tree, {'world', 'shoulder', 'forearm'}, parentless={'world'})
    assert frame == 'world' and 'its frame world, which has no parent, stands for it' in note
    # no single parentless stand-in: the first link below the root both have
    frame, note = comparison_frame(tree, {'world', 'other', 'shoulder', 'forearm'}, parentless={'world', 'other'})
    assert frame == 'shoulder' and 'does not publish the root link base' in note
    assert comparison_frame(tree, {'world'})[0] is None


def test_grade_names_the_first_wrong_link_and_its_joint():
    tree = KinematicTree.from_file(TILTED)
    grade = Grade(tree, 'base', 1e-6)
    for k, q in enumerate(configurations(tree, 5, seed=0)):
        want = tree.link_poses(q)
        got = {l: m.copy() for l, m in want.items()}
        if k == 3:  # the elbow's child and what hangs below it are off
            twist = tft.rotation_matrix(0.01, [0, 0, 1])
            got['forearm'] = got['forearm'].dot(twist)
            got['tool'] = got['forearm'].dot(tree.joints['tool_mount'].matrix)
        grade.add(k, q, want, got)
    assert grade.failing() == ['forearm', 'tool']
    verdict = grade.verdict()
    assert verdict.startswith('FAIL: forearm, rotation off by 0.01 rad in configuration 3; check joint elbow')
    report = '\n'.join(grade.report())
    assert 'forearm' in report and '<- wrong' in report and report.endswith(verdict)
    # the worst configuration, reproducible: every joint's value, the expected and the received pose
    q3 = configurations(tree, 5, seed=0)[3]
    assert 'configuration 3: ' + ', '.join(f'{n} = {v:.6g}' for n, v in q3.items()) in report
    assert '  forearm expected xyz' in report and '  forearm received xyz' in report


def test_a_stand_in_root_grades_every_link_and_blames_the_first_joint():
    """A course-style node: links under a parentless 'world', the root unpublished. Correct, it passes with every
    link graded; ignoring the first joint's angle, it fails on the first link, wrong in every configuration but
    the zero pose."""
    tree = KinematicTree.from_file(TILTED)
    configs = configurations(tree, 4, seed=0)
    first = tree.active_joints[0]
    right, wrong = Grade(tree, 'world', 1e-6), Grade(tree, 'world', 1e-6)
    for k, q in enumerate(configs):
        want = tree.link_poses(q)
        right.add(k, q, want, {l: m for l, m in want.items() if l != tree.root})
        lazy = tree.link_poses(dict(q, **{first: 0.0}))
        wrong.add(k, q, want, {l: m for l, m in lazy.items() if l != tree.root})
    assert right.verdict() == 'PASS' and right.links == [l for l in tree.links if l != tree.root]
    child = tree.joints[first].child
    assert wrong.verdict().startswith(f'FAIL: {child}, ') and f'check joint {first}' in wrong.verdict()
    assert 'zero pose' not in wrong.verdict()    # right at the zero pose, where the angle is 0
    always = Grade(tree, 'world', 1e-6)
    for k, q in enumerate(configs):               # a wrong fixed offset: wrong everywhere, the zero pose included
        want = tree.link_poses(q)
        always.add(k, q, want, {l: m.dot(tft.translation_matrix([0.01, 0, 0])) for l, m in want.items()})
    assert 'wrong in every configuration, the zero pose included' in always.verdict()


def test_missing_links_blame_the_closest_to_the_root():
    """A node that stops at a fork misses the links after it: the verdict names them, not the root."""
    panda = KinematicTree.from_file(robot_path('panda.urdf'))
    q = configurations(panda, 1)[0]
    want = panda.link_poses(q)
    stopped = Grade(panda, 'world', 1e-6)
    stopped.add(0, q, want, {l: m for l, m in want.items() if 'finger' not in l and l != panda.root})
    verdict = stopped.verdict()
    assert verdict.startswith('FAIL: publish a transform for panda_'), verdict    # a finger, not the root
    assert '(2 links never published: ' in verdict and 'panda_leftfinger' in verdict and 'panda_rightfinger' in verdict
    assert 'check joint panda_finger_joint' in verdict


def test_grade_pass_missing_and_non_finite():
    tree = KinematicTree.from_file(TILTED)
    q = configurations(tree, 2, seed=0)[1]
    want = tree.link_poses(q)
    ok = Grade(tree, 'base', 1e-6)
    ok.add(0, q, want, {l: m + 1e-9 for l, m in want.items()})
    assert ok.verdict() == 'PASS' and ok.failing() == []
    missing = Grade(tree, 'base', 1e-6)
    missing.add(0, q, want, {l: m for l, m in want.items() if l != 'tool'})
    assert missing.verdict().startswith('FAIL: publish a transform for tool')
    bad = Grade(tree, 'base', 1e-6)
    bad.add(0, q, want, dict(want, forearm=np.full((4, 4), np.nan)))
    assert 'not finite' in bad.verdict()


def test_rotation_error():
    a = tft.rotation_matrix(0.3, [0, 0.6, 0.8])
    assert abs(rotation_error(a, np.identity(4)) - 0.3) < 1e-12
    assert rotation_error(a, a) < 1e-7


def test_links_below_a_floating_joint_are_named_and_never_passed():
    path = os.path.join(os.path.dirname(TILTED), 'floating_base_arm.urdf')
    tree = KinematicTree.from_file(path)
    grade = Grade(tree, 'odom', 1e-6)
    q = configurations(tree, 1)[0]
    grade.add(0, q, tree.link_poses(q), {})
    assert grade.ungradable == ['body', 'arm'] and grade.links == []
    assert grade.verdict() == 'FAIL: no link can be graded: body, arm are below a floating joint'
    assert any(l.startswith('not graded (below a floating joint') for l in grade.report())


def test_a_floating_base_is_graded_relative_to_the_floating_joints_child():
    """Issue 25: below a floating joint (a humanoid's pelvis, a mobile base) every link is graded relative to the
    joint's child, whether the candidate publishes the floating joint's transform or not; robot_state_publisher
    (body -> arm only) passes, a wrong arm fails, and a candidate without the base is told to publish it."""
    tree = KinematicTree.from_file(os.path.join(os.path.dirname(TILTED), 'floating_base_arm.urdf'))
    assert tree.floating_base() == 'body'
    frame, note = comparison_frame(tree, {'body', 'arm'})
    assert frame == 'body' and 'odom_to_body is a floating joint' in note
    assert comparison_frame(tree, {'odom', 'arm'})[0] is None
    assert 'publishes no frame body' in comparison_frame(tree, {'odom', 'arm'})[1]
    for offset, verdict in ((0.0, 'PASS'), (0.01, 'FAIL: arm, rotation off')):
        grade = Grade(tree, frame, 1e-6, note)
        assert grade.links == ['arm']
        for k, q in enumerate(configurations(tree, 4, seed=1)):
            want = grade.reference_poses(q)
            assert set(want) == {'body', 'arm'}
            got = {'arm': tree.link_poses({'shoulder': q['shoulder'] + offset}, base='body')['arm']}
            grade.add(k, q, want, got)
        assert grade.verdict().startswith(verdict), grade.verdict()
    assert 'not graded' not in '\n'.join(Grade(tree, frame, 1e-6, note).report())   # odom is the root


MIMIC = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', 'urdf', 'mimic_gripper.urdf')


def test_a_missed_mimic_joint_is_named_and_the_score_counts_links_and_configurations():
    """Issue 26: a node that reads the mimic joint from joint_states (it is not there) misplaces finger2 whenever
    finger_joint1 moves; the verdict says the joint is a mimic, the score line counts what was right."""
    tree = KinematicTree.from_file(MIMIC)
    grade = Grade(tree, 'base', 1e-6)
    configs = configurations(tree, 6, seed=0)
    for k, q in enumerate(configs):
        got = tree.link_poses(dict(q, finger_joint2=0.0))      # the mimic left at 0
        grade.add(k, q, tree.link_poses(q), got)
    assert grade.verdict().startswith('FAIL: finger2, position off')
    assert 'check joint finger_joint2 (mimic of finger_joint1, multiplier -1, prismatic' in grade.verdict()
    right = sum(1 for q in configs if q['finger_joint1'] == 0.0)      # the zero pose
    assert grade.score() == f'score: 2/3 links, {right}/6 configurations'
    assert grade.report()[-3] == grade.score() and grade.report()[-1] == grade.verdict()
    # the grade: link poses right over links x configurations (two links right everywhere, finger2 in the zero pose)
    assert grade.report()[-2] == grade.grade_line() == (f'grade: {grade_of(2 * 6 + right, 3, 6):.1f} '
                                                        f'({2 * 6 + right} of 18 link poses right: 3 links x 6 '
                                                        'configurations)')
    assert 0 < grade_of(2 * 6 + right, 3, 6) < 100
    ok = Grade(tree, 'base', 1e-6)
    for k, q in enumerate(configs):
        ok.add(k, q, tree.link_poses(q), tree.link_poses(q))
    assert ok.score() == 'score: 3/3 links, 6/6 configurations' and ok.verdict() == 'PASS'
    assert ok.grade_line().startswith('grade: 100.0 (18 of 18 ')
