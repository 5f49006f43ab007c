"""robot_ai.grading.gradebook: the grade rule, the LMS identifiers of students' folders and files, and a CSV written as
the class goes, so that a grader killed with SIGKILL leaves every verdict it printed (issue 56)."""
import csv
import os
import signal
import subprocess
import sys

import pytest

from robot_ai.grading.candidates import Result
from robot_ai.grading.gradebook import Gradebook, grade_line, grade_of, identity


def test_the_grade_is_the_share_of_link_poses_right_and_only_a_pass_is_100():
    assert grade_of(140, 7, 20) == 100.0
    assert grade_of(139, 7, 20) == 99.2
    assert grade_of(9999, 100, 100) == 99.9          # floored: one wrong pose is never shown as 100
    assert grade_of(0, 7, 20) == 0.0 and grade_of(5, 0, 0) == 0.0
    assert grade_line(130, 7, 20) == 'grade: 92.8 (130 of 140 link poses right: 7 links x 20 configurations)'
    # the judge's report line is read back as the number
    r = Result.of('bob', 'score: 5/7 links, 18/20 configurations\n' + grade_line(130, 7, 20) + '\nFAIL: x', 1.0,
                  ['x'])
    assert r.grade == 92.8 and r.score == '5/7 links, 18/20 configurations'
    assert Result.of('bob', 'FAIL: the candidate node exited', 1.0, []).grade is None


@pytest.mark.parametrize('name, source, id_from, expected', [
    ('Jane Doe_123456_assignsubmission_file_', '', 'folder', ('Jane Doe', '123456')),        # Moodle's download
    ('alice', 'doejane_LATE_98765_4321_fk_node.py', 'file', ('doejane', '98765')),          # Canvas's, late
    ('alice', 'doejane_98765_4321_fk_node.py', 'file', ('doejane', '98765')),
    ('alice', 'doejane_98765_4321_fk_node.py', 'folder', ('alice', 'alice')),
    ('student07', 'solution.py', 'file', ('solution', 'solution')),
    ('student07', '', 'folder', ('student07', 'student07')),
])
def test_students_are_named_as_the_lms_download_names_them(name, source, id_from, expected):
    who = identity(name, source, id_from)
    assert (who.name, who.id) == expected


def results():
    return {'Jane Doe_11_assignsubmission_file_': Result('Jane Doe_11_assignsubmission_file_', 'PASS',
                                                         '7/7 links, 20/20 configurations', '', 12.5, 100.0,
                                                         'fk.py'),
            'Bob Roe_12_assignsubmission_file_': Result('Bob Roe_12_assignsubmission_file_',
                                                        'FAIL: forearm, rotation off by 1 rad', '5/7 links, '
                                                        '3/20 configurations', 'forearm', 8.25, 71.4, 'fk.py')}


def read(path):
    with open(path, newline='') as f:
        return list(csv.reader(f))


def test_each_format_has_the_columns_its_lms_imports(tmp_path):
    students = sorted(list(results()) + ['=cmd_13_assignsubmission_file_'])
    path = str(tmp_path / 'grades.csv')
    book = Gradebook(path, 'robot_ai', students)
    book.finish(results())
    rows = read(path)
    assert rows[0] == ['student', 'id', 'grade', 'verdict', 'score', 'first_wrong_link', 'seconds']
    assert rows[1] == ["'=cmd_13_assignsubmission_file_", '13', '', 'not graded (check_fk was stopped)', '', '', '']
    assert rows[2][:4] == ['Bob Roe_12_assignsubmission_file_', '12', '71.4', 'FAIL: forearm, rotation off by 1 rad']
    assert rows[2][-1] == '8.2' or rows[2][-1] == '8.3'
    Gradebook(path, 'moodle', students).finish(results())
    rows = read(path)
    assert rows[0] == ['Identifier', 'Full name', 'Grade', 'Maximum Grade', 'Feedback comments']
    assert rows[2] == ['Participant 12', 'Bob Roe', '71.4', '100',
                       'FAIL: forearm, rotation off by 1 rad [5/7 links, 3/20 configurations]']
    assert rows[3][:4] == ['Participant 11', 'Jane Doe', '100.0', '100']
    assert rows[1][2] == ''              # not graded: no grade, so the LMS keeps what it has
    Gradebook(path, 'canvas', students, assignment='FK node (4711)').finish(results())
    rows = read(path)
    assert rows[0] == ['Student', 'ID', 'SIS User ID', 'SIS Login ID', 'Section', 'FK node (4711)']
    assert rows[3] == ['Jane Doe', '11', '', '', '', '100.0']
    with pytest.raises(ValueError, match='moodle'):
        Gradebook(path, 'blackboard', students)


KILLED = """
import os, signal, sys
from robot_ai.grading.candidates import Result
from robot_ai.grading.gradebook import Gradebook
book = Gradebook(sys.argv[1], 'robot_ai', ['a', 'b', 'c'])
book.start()
book.add('b', Result('b', 'PASS', '7/7 links, 2/2 configurations', '', 1.0, 100.0))
book.add('a', Result('a', 'FAIL: x', '0/7 links, 0/2 configurations', '', 2.0, 0.0))
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_grader_killed_with_sigkill_leaves_the_header_and_every_row_it_wrote(tmp_path):
    path = str(tmp_path / 'grades.csv')
    proc = subprocess.run([sys.executable, '-c', KILLED, path], capture_output=True, text=True, timeout=60)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    rows = read(path)
    assert [r[:4] for r in rows] == [['student', 'id', 'grade', 'verdict'], ['b', 'b', '100.0', 'PASS'],
                                     ['a', 'a', '0.0', 'FAIL: x']]
    # the end of a run puts the class in order, the students not graded named, in place of the rows so far
    book = Gradebook(path, 'robot_ai', ['a', 'b', 'c'])
    book.finish({'b': Result('b', 'PASS', '', '', 1.0, 100.0)})
    assert [r[0] for r in read(path)] == ['student', 'a', 'b', 'c'] and not os.path.exists(path + '.partial')
