"""robot_ai.urdf_source: URDF or xacro -> URDF, $(find) through ROS_PACKAGE_PATH, one-line errors (issue 25)."""
import os

import pytest

from fk_helpers import write_xacro_package
from robot_ai.kinematics import KinematicTree
from robot_ai.urdf_source import XacroError, expand, is_xacro, main, parse_mappings

HERE = os.path.dirname(os.path.realpath(__file__))


@pytest.fixture
def arm(tmp_path, monkeypatch):
    path = write_xacro_package(str(tmp_path))
    monkeypatch.setenv('ROS_PACKAGE_PATH', str(tmp_path) + os.pathsep + os.environ.get('ROS_PACKAGE_PATH', ''))
    return path


def test_xacro_with_find_include_macros_and_arguments(arm):
    tree = KinematicTree.from_xml_string(expand(arm))
    assert tree.links == ['base', 'shoulder', 'elbow'] or sorted(tree.links) == ['base', 'elbow', 'shoulder']
    tree = KinematicTree.from_xml_string(expand(arm, {'hand': 'true'}))
    assert 'hand' in tree.links and abs(tree.joints['elbow_joint'].xyz[2] - 0.4) < 1e-12


def test_a_plain_urdf_is_returned_as_it_is():
    path = os.path.join(HERE, '..', 'urdf', 'mimic_gripper.urdf')
    with open(path) as f:
        assert expand(path) == f.read()
    assert not is_xacro(path, 'x') and is_xacro('a.urdf.xacro', '') and is_xacro('a.urdf', '<robot xmlns:xacro="x">')


def test_errors_are_one_line_naming_the_file_and_the_cause(arm, tmp_path, monkeypatch, capsys):
    with open(arm) as f:
        text = f.read()
    cases = {'nopkg.xacro': (text.replace('$(find my_arm_description)', '$(find no_such_pkg)'),
                             'package no_such_pkg not found: put it on ROS_PACKAGE_PATH'),
             'macro.xacro': (text.replace('xacro:segment name="shoulder"', 'xacro:segmnt name="shoulder"'),
                             'unknown macro name: xacro:segmnt'),
             'arg.xacro': (text.replace('<xacro:arg name="hand" default="false"/>', ''),
                           'argument hand is not set: give hand:=value'),
             'broken.xacro': ('<robot xmlns:xacro="x"><link name="a"', 'broken.xacro')}
    for name, (source, cause) in cases.items():
        path = tmp_path / name
        path.write_text(source)
        with pytest.raises(XacroError) as caught:
            expand(str(path))
        message = str(caught.value)
        assert message.startswith(str(path)) and cause in message and '\n' not in message, message
    with pytest.raises(XacroError, match='cannot read'):
        expand(str(tmp_path / 'missing.xacro'))
    assert main([str(tmp_path / 'macro.xacro')]) == 1
    assert capsys.readouterr().err.strip().splitlines()[-1].startswith('xacro: ')


def test_arguments_and_the_command_line(arm, capsys):
    assert parse_mappings(['hand:=true', 'arm_id=panda']) == {'hand': 'true', 'arm_id': 'panda'}
    with pytest.raises(XacroError, match='name:=value'):
        parse_mappings(['hand'])
    assert main([arm, 'hand:=true']) == 0
    assert '<link name="hand"/>' in capsys.readouterr().out


def test_the_reference_robots_read_the_same_through_it():
    """The PR2's expanded URDF keeps xacro macro calls in blocks nobody reads: xacro refuses them, and the file is
    then taken as it is; the others expand to the very same kinematics."""
    import numpy as np
    from fk_helpers import robot_path
    for name in ('kuka_lwr_arm.urdf', 'panda.urdf', 'pr2.urdf', 'ur5.urdf'):
        raw = KinematicTree.from_file(robot_path(name))
        through = KinematicTree.from_xml_string(expand(robot_path(name)))
        assert raw.links == through.links, name
        q = {n: 0.3 for n in raw.active_joints}
        for link, pose in raw.link_poses(q).items():
            assert np.array_equal(pose, through.link_poses(q)[link]), (name, link)
    with open(robot_path('pr2.urdf')) as f:
        assert expand(robot_path('pr2.urdf')) == f.read()
