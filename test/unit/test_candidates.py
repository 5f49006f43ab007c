"""robot_ai.grading.candidates and robot_ai.urdf_compat: students' files as they wrote them (issue 26), without a
roscore."""
import os
import sys

import pytest

from fk_helpers import robot_path
from robot_ai import urdf_compat
from robot_ai.grading import candidates
from robot_ai.grading.candidates import Result, command, find_node, is_python, syntax_verdict

HERE = os.path.dirname(os.path.realpath(__file__))
COURSE_PY2 = os.path.join(HERE, '..', 'course_fk_py2.py')


def write(folder, name, text, mode='w'):
    path = os.path.join(folder, name)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, mode) as f:
        f.write(text)
    return path


@pytest.mark.parametrize('first, expected', [('#!/usr/bin/env python\n', True), ('#!/usr/bin/python2.7\n', True),
                                             ('#!/usr/bin/env python3\n', True), ('#!/bin/sh\n', False)])
def test_a_python_file_runs_with_our_python_whatever_its_first_line(tmp_path, first, expected):
    path = write(tmp_path, 'node', first + 'print(1)\n')
    assert is_python(path) is expected
    assert command(path, sys.executable) == ([sys.executable, path] if expected else [path])
    assert is_python(write(tmp_path, 'solution.py', 'import rospy\n'))       # .py with no #! line


def test_the_course_py2_file_is_named_with_its_line():
    assert syntax_verdict(COURSE_PY2) == ('FAIL: course_fk_py2.py line 59 is Python 2 (print statement): ROS Noetic '
                                          'runs Python 3; write print(...) (line: print "forward kinematics node '
                                          'started")')


@pytest.mark.parametrize('source, construct', [
    ('print "x"\n', 'print statement'),
    ('import sys\nprint >>sys.stderr, "x"\n', 'print >>file'),
    ('exec "x = 1"\n', 'exec statement'),
    ('try:\n    pass\nexcept ValueError, e:\n    pass\n', 'except X, e'),
    ('x = 0777\n', 'octal literal 0NNN'),
    ('raise ValueError, "bad"\n', 'raise E, message'),
    ('x = `1`\n', 'backquotes'),
    ('if 1 <> 2:\n    pass\n', '<> operator'),
    ('x = 10L\n', 'long literal 10L'),
])
def test_python_2_constructs(tmp_path, source, construct):
    verdict = syntax_verdict(write(tmp_path, 'solution.py', '# a student\n' + source))
    assert verdict.startswith('FAIL: solution.py line ') and ' is Python 2 (' + construct in verdict, verdict
    assert 'ROS Noetic runs Python 3' in verdict


def test_other_syntax_errors_name_file_and_line_and_good_files_pass(tmp_path):
    verdict = syntax_verdict(write(tmp_path, 'solution.py', 'import rospy\n\ndef f(:\n    pass\n'))
    assert verdict.startswith('FAIL: solution.py line 3: SyntaxError: ') and 'the node cannot start' in verdict
    assert syntax_verdict(write(tmp_path, 'good.py', 'import rospy\nprint("x")\n')) is None
    assert 'not a Python source file' in syntax_verdict(write(tmp_path, 'nul.py', b'x = 1\0\n', 'wb'))
    assert syntax_verdict(str(tmp_path / 'missing.py')).startswith('FAIL: cannot read')


def test_the_node_of_a_student_folder(tmp_path):
    write(tmp_path, 'a/README.md', 'init_node\n')
    write(tmp_path, 'a/src/helpers.py', 'import rospy\nrospy.init_node("x")\n')
    node = write(tmp_path, 'a/src/deep/solution.py', 'rospy.init_node("fk")\nrospy.Subscriber("joint_states")\n')
    assert find_node(str(tmp_path / 'a')) == node          # the one that reads joint_states wins
    write(tmp_path, 'b/notes.txt', 'nothing\n')
    assert find_node(str(tmp_path / 'b')) is None
    write(tmp_path, 'c/.git/hooks/x.py', 'rospy.init_node("x")\n')
    assert find_node(str(tmp_path / 'c')) is None            # hidden folders are not the student's


def test_a_verdict_as_a_csv_row():
    out = 'check_fk: ...\nscore: 5/7 links, 18/20 configurations\n(graded in 3.0 s)\nFAIL: forearm, rotation off\n'
    r = Result.of('alice', out, 3.25, ['base', 'shoulder', 'forearm', 'tool'])
    assert (r.verdict, r.score, r.first_wrong_link) == ('FAIL: forearm, rotation off',
                                                       '5/7 links, 18/20 configurations', 'forearm')
    assert r.line() == 'alice: FAIL: forearm, rotation off [5/7 links, 18/20 configurations] (3.2 s)'
    assert Result.of('bob', 'PASS\n', 1.0, ['base']).first_wrong_link == ''
    assert Result.of('carol', '', 0.0, []).verdict == 'no verdict'


def test_from_parameter_server_has_ros_1s_meaning(monkeypatch):
    """The venv's urdf_parser_py answers URDF.from_parameter_server() (robot_ai_urdf_compat.pth installs it):
    the key searched up the namespaces, a global key as it is, the PR2's old transmissions left out."""
    import rospy
    from urdf_parser_py.urdf import URDF
    assert hasattr(URDF, 'from_parameter_server')
    with open(os.path.join(HERE, '..', 'urdf', 'mimic_gripper.urdf')) as f:
        xml = f.read()
    params = {'/a/robot_description': xml, '/other': xml.replace('mimic_gripper', 'other')}
    monkeypatch.setattr(rospy, 'search_param',
                        lambda key: '/a/robot_description' if key == 'robot_description' else None)
    monkeypatch.setattr(rospy, 'get_param', lambda key: params[key])
    assert URDF.from_parameter_server().name == 'mimic_gripper'
    assert URDF.from_parameter_server(key='/other').name == 'other'
    with pytest.raises(KeyError):
        URDF.from_parameter_server(key='missing')
    with open(robot_path('pr2.urdf')) as f:       # urdfdom-py alone raises on its old <transmission> blocks
        params['/a/robot_description'] = f.read()
    assert len(URDF.from_parameter_server().links) == 83


def test_patch_adds_the_method_only_where_it_is_missing():
    class Robot:
        @classmethod
        def from_xml_string(cls, xml):
            return xml

    class Own(Robot):
        @classmethod
        def from_parameter_server(cls, key='x'):
            return 'own'
    module = type(sys)('fake')
    module.Robot = Robot
    urdf_compat.patch(module)
    assert Robot.from_parameter_server.__func__ is urdf_compat.from_parameter_server
    module.Robot = Own
    urdf_compat.patch(module)
    assert Own.from_parameter_server() == 'own'
    assert 'robot_ai.urdf_compat' in urdf_compat.pth_line() and candidates.MAX_SOURCE > 0


def test_find_node_reads_regular_files_only_and_never_waits(tmp_path):
    """Issue 40: a folder holding fk.py -> /proc/kmsg hung the class run for good, and 5,000 links to one 4 MiB
    file cost 82 s before anything was bounded. Links (in the folder or out of it), FIFOs and devices are never
    opened; a bounded number of names is looked at."""
    import threading
    import time
    folder = tmp_path / 'student'
    folder.mkdir()
    (folder / 'fk.py').symlink_to('/proc/kmsg')
    os.mkfifo(folder / 'pipe.py')
    big = tmp_path / 'big.py'
    big.write_bytes(b'import rospy\nrospy.init_node("x")\n' + b'#' * (4 * 1024 * 1024))
    for i in range(200):
        (folder / f'link{i}.py').symlink_to(big)
    (folder / 'real.py').write_text('import rospy\nrospy.init_node("fk")\nrospy.Subscriber("joint_states", None)\n')
    found = []
    t = time.monotonic()
    worker = threading.Thread(target=lambda: found.append(find_node(str(folder))), daemon=True)
    worker.start()
    worker.join(10)
    assert not worker.is_alive(), 'find_node waited on a FIFO or a device'
    assert found == [str(folder / 'real.py')] and time.monotonic() - t < 5
    with pytest.raises(OSError):
        candidates.read_head(str(folder / 'pipe.py'))
    assert find_node(str(folder), max_files=3) is None      # bounded: real.py is not among the first names


def test_the_first_wrong_link_is_the_one_the_verdict_says_to_fix():
    """Issue 40: the CSV named the root as the first wrong link of a 'frames the URDF does not have' verdict."""
    from robot_ai.grading.candidates import first_wrong_link
    links = ['base', 'shoulder', 'forearm', 'tool']
    assert first_wrong_link('FAIL: forearm, rotation off by 0.1 rad', links) == 'forearm'
    assert first_wrong_link('FAIL: publish a transform for tool (and 2 more)', links) == 'tool'
    assert first_wrong_link('FAIL: tool was not published in 3 of 20 configurations', links) == 'tool'
    assert first_wrong_link('FAIL: the candidate publishes frames the URDF does not have (a, b) and none of its 4 '
                            'links: is it written for another robot? This one\'s root is base', links) == ''
    assert first_wrong_link('FAIL: the candidate node exited with status 1', links) == ''
    assert first_wrong_link('PASS', links) == ''


def test_a_ctrl_c_while_the_venv_starts_ends_the_interpreter_quietly(tmp_path):
    """launch.test's Ctrl-C at any moment of a start: a SIGINT while site ran the .pth line printed a traceback
    through robot_ai.urdf_compat; now that interpreter ends at once with 130, an interrupted program's status."""
    import subprocess
    fake = tmp_path / 'robot_ai'
    fake.mkdir()
    (fake / '__init__.py').write_text('')
    (fake / 'urdf_compat.py').write_text('raise KeyboardInterrupt\n')
    done = subprocess.run([sys.executable, '-S', '-c', urdf_compat.pth_line()], capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=str(tmp_path)), timeout=60)
    assert done.returncode == 130 and done.stderr == '', done.stderr
