#!/usr/bin/env python3
"""check_fk as a student runs it: it passes robot_state_publisher and forward_kinematics on every reference robot,
fails a node that rotates by euler angles axis * q on a URDF with a tilted axis (naming the link), passes that
same node where every axis is along x, y or z, and gives a clear verdict for a node that crashes or stays silent."""
import glob
import os
import shutil
import resource
import signal
import socket
import subprocess
import sys
import tempfile
import time
import unittest

import rostest
from robot_ai.grading import sandbox

sys.path.insert(0, os.path.dirname(os.path.realpath(__file__)))
from fk_helpers import ROBOTS_DIR, write_xacro_package  # noqa: E402
from ros_helpers import cases_of  # noqa: E402

HERE = os.path.dirname(os.path.realpath(__file__))
TILTED = os.path.join(HERE, 'urdf', 'tilted_axis_arm.urdf')
ROBOTS = sorted(glob.glob(os.path.join(ROBOTS_DIR, '*.urdf'))
                + glob.glob(os.path.join(ROBOTS_DIR, 'fixtures', '*.urdf')))


def check_fk(model, candidate, *args, mistake='euler', parent='world', mark=''):
    env = dict(os.environ, WRONG_FK_MISTAKE=mistake, COURSE_FK_MISTAKE=mistake, COURSE_FK_PARENT=parent,
               COURSE_FK_MARK=mark)
    proc = subprocess.run(['rosrun', 'robot_ai', 'check_fk', '--model', model, '--candidate', candidate] + list(args),
                          capture_output=True, text=True, timeout=300, env=env)
    return proc.returncode, proc.stdout.strip().splitlines(), proc.stderr


class TestCheckFk(unittest.TestCase):

    def assert_verdict(self, model, candidate, status, start, *args, mistake='euler', parent='world'):
        code, lines, err = check_fk(model, candidate, *args, mistake=mistake, parent=parent)
        verdict = [l for l in lines if l.startswith(('PASS', 'FAIL'))]
        self.assertTrue(verdict, '%s %s: no verdict\n%s\n%s' % (candidate, model, '\n'.join(lines), err[-2000:]))
        self.assertTrue(verdict[-1].startswith(start), '%s %s:\n%s' % (candidate, model, '\n'.join(lines)))
        self.assertEqual(code, status, '\n'.join(lines))
        return lines

    def test_passes_the_references_on_every_robot(self):
        self.assertGreaterEqual(len(ROBOTS), 8)
        for model in ROBOTS + [TILTED]:
            for candidate in ('robot_state_publisher/robot_state_publisher', 'robot_ai/forward_kinematics'):
                lines = self.assert_verdict(model, candidate, 0, 'PASS', '--configurations', '8')
                single = os.path.basename(model) == 'one_link.urdf'  # nothing to publish, nothing to compare
                self.assertIn('single link with no joint' if single else '8 configurations compared',
                              '\n'.join(lines))

    def test_a_7_joint_arm_in_under_a_minute(self):
        t = time.time()
        lines = self.assert_verdict(os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf'), 'robot_ai/forward_kinematics', 0,
                                    'PASS')
        self.assertIn('50 configurations compared', '\n'.join(lines))
        self.assertLess(time.time() - t, 60.0)

    def test_fails_a_wrong_node_where_the_mistake_shows_and_names_the_link(self):
        lines = self.assert_verdict(TILTED, 'robot_ai/wrong_fk_euler.py', 1, 'FAIL: forearm', '--configurations', '10')
        text = '\n'.join(lines)
        self.assertIn('check joint elbow', lines[-1])
        self.assertTrue(lines[-2].startswith('(graded in '))
        self.assertIn('frames the URDF does not have (not graded): world', text)
        table = {l.split()[0]: l for l in lines if l.split() and l.split()[0] in ('shoulder', 'upper_arm', 'forearm',
                                                                                  'tool') and not l.startswith(' ')}
        self.assertNotIn('wrong', table['upper_arm'])   # above the tilted joint, the node is right
        self.assertIn('<- wrong', table['forearm'])
        self.assertIn('<- wrong', table['tool'])

    def test_passes_the_same_wrong_node_where_every_axis_is_x_y_or_z(self):
        self.assert_verdict(os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf'), 'robot_ai/wrong_fk_euler.py', 0, 'PASS',
                            '--configurations', '10')

    def test_fails_a_node_that_ignores_rpy_or_publishes_nan(self):
        ur5 = os.path.join(ROBOTS_DIR, 'ur5.urdf')   # base_link_inertia's joint has rpy 0 0 pi
        lines = self.assert_verdict(ur5, 'robot_ai/wrong_fk_euler.py', 1, 'FAIL: ', '--configurations', '5',
                                    mistake='rpy')
        self.assertIn('rpy', lines[-1])
        self.assert_verdict(ur5, 'robot_ai/wrong_fk_euler.py', 1, 'FAIL: the candidate published a non-finite',
                            '--configurations', '5', mistake='nan')

    def test_clear_verdicts_for_broken_candidates(self):
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        self.assert_verdict(kuka, 'robot_ai/no_such_node', 1, 'FAIL: the candidate node exited')
        self.assertIn("[rosrun] Couldn't find executable named no_such_node",   # rosrun's own words, quoted
                      '\n'.join(check_fk(kuka, 'robot_ai/no_such_node')[1]))
        t = time.time()
        self.assert_verdict(kuka, 'robot_ai/silent_fk.py', 1, 'FAIL: the candidate published nothing',
                            '--timeout', '3')
        self.assertLess(time.time() - t, 30.0)
        code, _, err = check_fk('/no/such.urdf', 'robot_ai/forward_kinematics')
        self.assertEqual(code, 2)
        self.assertIn('cannot read the model', err)
        code, _, err = check_fk(kuka, 'forward_kinematics')
        self.assertEqual(code, 2)
        self.assertIn('PACKAGE/TYPE', err)


    # ------------------------------------------------------------------- students' files as they wrote them (issue 26)
    def test_a_python_2_file_is_a_verdict_that_names_the_line(self):
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        code, lines, err = check_fk(kuka, 'robot_ai/course_fk_py2.py')
        self.assertEqual(code, 1, lines)
        self.assertEqual(lines[-1], 'FAIL: course_fk_py2.py line 59 is Python 2 (print statement): ROS Noetic runs '
                                    'Python 3; write print(...) (line: print "forward kinematics node started")')
        self.assertNotIn('Traceback', err + '\n'.join(lines))
        with tempfile.TemporaryDirectory() as folder:
            for source, verdict in (
                    ('import rospy\ntry:\n    pass\nexcept ValueError, e:\n    pass\n',
                     'FAIL: solution.py line 5 is Python 2 (except X, e): ROS Noetic runs Python 3; '
                     'write except X as e'),
                    ('import rospy\n\ndef callback(msg:\n    pass\n',
                     'FAIL: solution.py line 4: SyntaxError: ')):
                path = os.path.join(folder, 'solution.py')
                with open(path, 'w') as f:
                    f.write('#!/usr/bin/env python\n' + source)
                code, lines, err = check_fk(kuka, path)
                self.assertEqual(code, 1, lines)
                self.assertTrue(lines[-1].startswith(verdict), lines)
                self.assertNotIn('Traceback', err)

    def test_a_course_node_runs_unchanged_whatever_python_its_first_line_names(self):
        """The course's file as a student hands it in (a path, not a package's node), its #! line naming a Python
        this machine does not have: it runs with the package's Python, URDF.from_parameter_server() included."""
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        with tempfile.TemporaryDirectory() as folder:
            path = os.path.join(folder, 'solution.py')
            with open(os.path.join(HERE, 'course_fk.py')) as f:
                text = f.read()
            with open(path, 'w') as f:
                f.write(text.replace('#!/usr/bin/env python\n', '#!/usr/bin/env python2\n', 1))
            self.assert_verdict(kuka, path, 0, 'PASS', '--configurations', '5', mistake='none')

    def test_from_parameter_server_under_plain_rosrun_searches_up_the_namespaces(self):
        """rosrun robot_ai course_fk.py in /grader/deeper: the skeleton's URDF.from_parameter_server() finds
        /grader/robot_description (ROS 1's search_param), and the node publishes the KUKA's frames."""
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        with open(kuka) as f:
            xml = f.read()
        setter = subprocess.run([sys.executable, '-c', 'import rospy, sys; '
                                 'rospy.set_param("/grader/robot_description", sys.stdin.read())'],
                                input=xml, text=True, capture_output=True, timeout=60)
        self.assertEqual(setter.returncode, 0, setter.stderr)
        # a user's shell, the venv first on PATH: rostest puts a `python` of its own before it (a link to the Python
        # that runs rostest, which outside the venv's folder no longer finds the venv)
        path = os.pathsep.join(p for p in os.environ['PATH'].split(os.pathsep) if 'rostest_bin_hook' not in p)
        node = subprocess.Popen(['rosrun', 'robot_ai', 'course_fk.py', '__ns:=/grader/deeper', '/tf:=/grader/tf'],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, preexec_fn=os.setsid,
                                env=dict(os.environ, COURSE_FK_MISTAKE='none', PATH=path))
        pub = subprocess.Popen(['rostopic', 'pub', '-r', '5', '/grader/deeper/joint_states', 'sensor_msgs/JointState',
                                '{name: [lwr_arm_0_joint], position: [0.3]}'], stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL, preexec_fn=os.setsid)
        try:
            try:
                echo = subprocess.run(['rostopic', 'echo', '-n', '1', '/grader/tf'], capture_output=True, text=True,
                                      timeout=90)
            except subprocess.TimeoutExpired:
                os.killpg(node.pid, signal.SIGINT)
                raise AssertionError('no /grader/tf in 90 s; the node said:\n' +
                                     node.communicate(timeout=20)[0].decode(errors='replace')[-3000:])
            self.assertIn('lwr_arm_1_link', echo.stdout, echo.stderr)
        finally:
            for proc in (pub, node):
                if proc.poll() is None:
                    os.killpg(proc.pid, signal.SIGINT)
                    proc.wait(20)
            subprocess.run(['rosparam', 'delete', '/grader'], capture_output=True, timeout=30)
        self.assertNotIn('AttributeError', node.stdout.read().decode(errors='replace'))

    def test_a_missed_mimic_joint_is_named_and_the_score_counts(self):
        gripper = os.path.join(HERE, 'urdf', 'mimic_gripper.urdf')
        lines = self.assert_verdict(gripper, 'robot_ai/course_fk.py', 1, 'FAIL: finger2, position off',
                                    '--configurations', '10', mistake='none')
        self.assertIn('check joint finger_joint2 (mimic of finger_joint1, multiplier -1, prismatic', lines[-1])
        score = [l for l in lines if l.startswith('score: ')]
        self.assertEqual(len(score), 1, lines)
        self.assertRegex(score[0], r'^score: 2/3 links, \d/10 configurations$')
        lines = self.assert_verdict(gripper, 'robot_ai/forward_kinematics', 0, 'PASS', '--configurations', '10')
        self.assertIn('score: 3/3 links, 10/10 configurations', lines)

    def test_expect_fail_for_a_course_test_that_a_wrong_node_is_caught(self):
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        self.assert_verdict(kuka, 'robot_ai/course_fk.py', 0, 'FAIL: lwr_arm_1_link', '--configurations', '5',
                            '--expect', 'fail', mistake='first')
        self.assert_verdict(kuka, 'robot_ai/forward_kinematics', 1, 'PASS', '--configurations', '5',
                            '--expect', 'fail')

    def test_a_class_at_once(self):
        """--candidates DIR: one folder per student (a right node, a wrong one, Python 2, one that dies, a silent
        one, none at all): a line each, a CSV, and one student's failure stops nobody."""
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        with open(os.path.join(HERE, 'course_fk.py')) as f:
            course = f.read()
        default = "os.environ.get('COURSE_FK_MISTAKE', 'none')"
        self.assertIn(default, course)
        students = {'alice': course, 'bob': open(os.path.join(HERE, 'course_fk_py2.py')).read(),
                    'carol': course.replace(default, "'first'"), 'dave': course.replace(default, "'die'"),
                    'erin': open(os.path.join(HERE, 'silent_fk.py')).read(), 'frank': None,
                    '=2+5': None, '@SUM(9+9)': None}      # issue 40: names a spreadsheet would evaluate
        with tempfile.TemporaryDirectory() as folder:
            for name, text in students.items():
                os.makedirs(os.path.join(folder, 'class', name, 'src'))
                with open(os.path.join(folder, 'class', name, 'README.md'), 'w') as f:
                    f.write('my solution\n')
                if text is not None:
                    with open(os.path.join(folder, 'class', name, 'src', 'solution.py'), 'w') as f:
                        f.write(text)
            csv_path = os.path.join(folder, 'grades.csv')
            env = dict(os.environ)
            env.pop('COURSE_FK_MISTAKE', None)
            proc = subprocess.run(['rosrun', 'robot_ai', 'check_fk', '--model', kuka, '--candidates',
                                   os.path.join(folder, 'class'), '--configurations', '5', '--timeout', '3',
                                   '--csv', csv_path], capture_output=True, text=True, timeout=600, env=env)
            self.assertEqual(proc.returncode, 0, proc.stdout + proc.stderr)
            lines = proc.stdout.splitlines()
            for name in students:
                self.assertEqual(len([l for l in lines if l.startswith(name + ': ')]), 1, (name, lines))
            import csv
            with open(csv_path) as f:
                rows = {r['student']: r for r in csv.DictReader(f)}
            # issue 41: a report names the student's own file, never the sandbox's copy, and has a score line
            reports = os.path.join(folder, 'grades_reports')
            texts = {}
            for report in sorted(os.listdir(reports)):
                with open(os.path.join(reports, report)) as f:
                    text = f.read()
                name = report.split('_', 1)[1][:-len('.txt')]
                texts[name] = text
                self.assertIn(os.path.join(folder, 'class', name, 'src', 'solution.py'), text, report)
                self.assertNotIn('check_fk_class_', text, report)
                self.assertEqual(len([l for l in text.splitlines() if l.startswith('score: ')]), 1, text)
            self.assertEqual(sorted(r.split('_', 1)[1] for r in os.listdir(reports)),
                             [f'{n}.txt' for n in sorted(students) if students[n] is not None])
        # OWASP's advice: a cell that starts as a formula gets a leading apostrophe, and nothing else changes
        self.assertEqual(sorted(rows), sorted(["'" + n if n[0] in '=@' else n for n in students]))
        self.assertTrue(rows["'=2+5"]['verdict'].startswith('FAIL: no node found'), rows)
        for name in ('bob', 'erin', 'frank'):      # nothing graded: none of the 8 links right, still a score
            self.assertEqual(rows[name]['score'], '0/8 links, 0/5 configurations', rows[name])
        self.assertRegex(rows['dave']['score'], r'^\d/8 links, \d/5 configurations$')
        self.assertEqual(rows['alice']['verdict'], 'PASS')
        self.assertEqual(rows['alice']['score'], '8/8 links, 5/5 configurations')
        self.assertTrue(rows['bob']['verdict'].startswith('FAIL: solution.py line 59 is Python 2'), rows['bob'])
        self.assertTrue(rows['carol']['verdict'].startswith('FAIL: lwr_arm_1_link'), rows['carol'])
        self.assertEqual(rows['carol']['first_wrong_link'], 'lwr_arm_1_link')
        self.assertTrue(rows['dave']['verdict'].startswith('FAIL: the candidate node exited'), rows['dave'])
        self.assertTrue(rows['erin']['verdict'].startswith('FAIL: the candidate published nothing'), rows['erin'])
        self.assertTrue(rows['frank']['verdict'].startswith('FAIL: no node found'), rows['frank'])
        for r in rows.values():
            float(r['seconds'])
        self.assertIn('1 of 8 PASS', proc.stdout)
        # issue 56: a numeric grade (0-100, the share of link poses right), an id, a crash named by its exception,
        # one duration per student (the CSV's, the line's and the report's)
        self.assertEqual((rows['alice']['grade'], rows['alice']['id']), ('100.0', 'alice'))
        for name in ('bob', 'erin', 'frank', 'dave'):
            self.assertEqual(rows[name]['grade'], '0.0', rows[name])
        self.assertTrue(0.0 < float(rows['carol']['grade']) < 100.0, rows['carol'])
        self.assertIn("exited with status 1: ValueError: 'tool_mount' is not in list", rows['dave']['verdict'])
        self.assertIn(f"alice: PASS [8/8 links, 5/5 configurations] ({rows['alice']['seconds']} s)", proc.stdout)
        self.assertIn(f"(graded in {rows['alice']['seconds']} s)", texts['alice'])

    # ------------------------------------------------------------------- course-style nodes (test/course_fk.py)
    def test_correct_course_style_nodes_pass_fast_or_slow(self):
        """Links under a parentless 'world' (or 'world' with the root unpublished), correct maths: PASS on the KUKA
        LWR and on the tilted arm, also with a 0.1 s callback, every link graded, within 40 s."""
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        for model, mistake in ((kuka, 'none'), (TILTED, 'none'), (kuka, 'sleep'), (TILTED, 'sleep')):
            t = time.time()
            lines = self.assert_verdict(model, 'robot_ai/course_fk.py', 0, 'PASS', mistake=mistake)
            self.assertLess(time.time() - t, 40.0, (model, mistake))
            text = '\n'.join(lines)
            self.assertIn('its frame world, which has no parent, stands for it', text)
            self.assertIn('50 configurations compared', text)
        # the course's own name for the parent: the KUKA's root is world_link, so the node publishes the root
        self.assert_verdict(kuka, 'robot_ai/course_fk.py', 0, 'PASS', '--configurations', '10', mistake='none',
                            parent='world_link')

    def test_slow_and_dropping_correct_nodes_pass_and_a_slow_wrong_one_is_named(self):
        """Issue 56: correct course nodes that sleep 0.4 and 1 s in their callback, and one that answers every other
        joint_states, PASS (a 0.4 s node failed with 'rotation off by 3.04 rad ... check joint shoulder_pan_joint'); a
        slow node with a wrong joint is failed on that joint, in the configuration where it shows."""
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        for model, mistake, pause, count in ((kuka, 'sleep', '0.4', '50'), (TILTED, 'sleep', '1', '12'),
                                             (kuka, 'every_other', '0', '50')):
            env = dict(os.environ, COURSE_FK_MISTAKE=mistake, COURSE_FK_SLEEP=pause)
            proc = subprocess.run(['rosrun', 'robot_ai', 'check_fk', '--model', model, '--candidate',
                                   'robot_ai/course_fk.py', '--configurations', count], capture_output=True,
                                  text=True, timeout=600, env=env)
            self.assertEqual(proc.returncode, 0, (mistake, pause, proc.stdout[-3000:], proc.stderr[-2000:]))
            self.assertEqual(proc.stdout.strip().splitlines()[-1], 'PASS')
            self.assertIn(f'{count} configurations compared', proc.stdout)
        fast = self.assert_verdict(TILTED, 'robot_ai/course_fk.py', 1, 'FAIL: shoulder,', '--configurations', '12',
                                   mistake='first')
        slow = subprocess.run(['rosrun', 'robot_ai', 'check_fk', '--model', TILTED, '--candidate',
                               'robot_ai/course_fk.py', '--configurations', '12'], capture_output=True, text=True,
                              timeout=600, env=dict(os.environ, COURSE_FK_MISTAKE='first', COURSE_FK_SLEEP='0.4'))
        self.assertEqual(slow.stdout.strip().splitlines()[-1], fast[-1])      # the same verdict, slow or not

    def test_wrong_course_style_nodes_fail_naming_the_first_wrong_link(self):
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        lines = self.assert_verdict(kuka, 'robot_ai/course_fk.py', 1, 'FAIL: lwr_arm_1_link, rotation off',
                                    '--configurations', '10', mistake='first')
        self.assertIn('check joint lwr_arm_0_joint', lines[-1])
        self.assertTrue(any(l.startswith('configuration ') and 'lwr_arm_0_joint = ' in l for l in lines), lines)
        self.assertTrue(any('lwr_arm_1_link expected xyz' in l for l in lines))
        self.assertTrue(any('lwr_arm_1_link received xyz' in l for l in lines))
        for mistake in ('order', 'rpy_order'):
            lines = self.assert_verdict(TILTED, 'robot_ai/course_fk.py', 1, 'FAIL: ', '--configurations', '10',
                                        mistake=mistake)
            self.assertIn('check joint ', lines[-1])

    def test_a_node_that_stops_at_a_fork_is_told_the_links_it_misses(self):
        lines = self.assert_verdict(os.path.join(ROBOTS_DIR, 'panda.urdf'), 'robot_ai/course_fk.py', 1,
                                    'FAIL: publish a transform for panda_', '--configurations', '5')
        self.assertIn('2 links never published', lines[-1])
        self.assertIn('finger', lines[-1])
        self.assertNotIn('panda_link0', lines[-1])

    def test_a_chatty_node_passes_and_a_node_for_another_robot_is_told_so(self):
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        self.assert_verdict(kuka, 'robot_ai/course_fk.py', 0, 'PASS', '--configurations', '20', mistake='chatty')
        lines = self.assert_verdict(TILTED, 'robot_ai/course_fk.py', 1,
                                    'FAIL: the candidate publishes frames the URDF does not have', mistake='kuka')
        self.assertIn('written for another robot', lines[-1])

    def test_a_flood_of_frame_names_is_bounded(self):
        """A correct node that also publishes 200 ever-new frame names a message and a 100 KB one: it passes, the
        report stays short, check_fk's memory stays bounded."""
        code, lines, err = check_fk(TILTED, 'robot_ai/course_fk.py', '--configurations', '20', mistake='flood')
        text = '\n'.join(lines)
        self.assertEqual(code, 0, text[-3000:] + err[-2000:])
        self.assertIn('frames the URDF does not have (not graded): ', text)
        self.assertLess(len(text), 5000)
        self.assertLess(max(len(l) for l in lines), 1500)
        peak_mib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        self.assertLess(peak_mib, 600, 'the largest process of the grades so far')

    def test_nodes_that_raise_are_quoted(self):
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        code, lines, _ = check_fk(kuka, 'robot_ai/course_fk.py', '--timeout', '3', mistake='raise')
        text = '\n'.join(lines)
        self.assertEqual(code, 1, text)
        self.assertIn('FAIL: the candidate published nothing', text)
        self.assertIn("AttributeError: module 'rospy' has no attribute 'logerror'", text)
        self.assertIn('its whole output: ', text)
        t = time.time()
        code, lines, _ = check_fk(kuka, 'robot_ai/course_fk.py', mistake='die')
        text = '\n'.join(lines)
        self.assertEqual(code, 1, text)
        self.assertIn('FAIL: the candidate node exited with status 1', text)
        self.assertIn("ValueError: 'tool_mount' is not in list", text)
        self.assertLess(time.time() - t, 20.0)


    def test_bad_input_is_one_line_with_status_2(self):
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        folder = tempfile.mkdtemp()
        self.addCleanup(shutil.rmtree, folder, True)
        xacro = os.path.join(folder, 'arm.urdf.xacro')
        with open(xacro, 'w') as f:
            f.write('<robot name="r" xmlns:xacro="http://www.ros.org/wiki/xacro"><link name="a"/>'
                    '<xacro:no_such_macro name="b"/></robot>')
        nested = os.path.join(folder, 'nested.urdf')
        with open(nested, 'w') as f:
            f.write('<robot name="n"><link name="root"/>' + '<link>' * 5000 + '</link>' * 5000 + '</robot>')
        for model, args, message in ((xacro, [], 'arm.urdf.xacro: xacro: unknown macro name: xacro:no_such_macro'),
                                     (nested, [], 'cannot read the model'),
                                     (kuka, ['--timeout', 'inf'], '--timeout one of at most 600 s'),
                                     (kuka, ['--configurations', '200000'], '--configurations must be 1 to 10000')):
            t = time.time()
            code, lines, err = check_fk(model, 'robot_ai/forward_kinematics', *args)
            self.assertEqual(code, 2, (args, lines, err))
            self.assertIn(message, err)
            self.assertNotIn('Traceback', err)
            self.assertLess(time.time() - t, 15)

    def test_a_xacro_model_with_find_and_arguments(self):
        """Issue 25: --model FILE.xacro --xacro-args: $(find pkg) through ROS_PACKAGE_PATH, the arguments passed."""
        folder = tempfile.mkdtemp()
        self.addCleanup(shutil.rmtree, folder, True)
        write_xacro_package(folder)
        arm = os.path.join(folder, 'my_arm_description', 'urdf', 'arm.urdf.xacro')
        saved = os.environ.get('ROS_PACKAGE_PATH', '')
        os.environ['ROS_PACKAGE_PATH'] = folder + os.pathsep + saved
        try:
            for args, links in (([], 3), (['--xacro-args', 'hand:=true'], 4)):
                lines = self.assert_verdict(arm, 'robot_ai/forward_kinematics', 0, 'PASS', '--configurations', '5',
                                            *args)
                self.assertIn(f'({links} links,', lines[0])
            code, lines, err = check_fk(arm, 'robot_ai/forward_kinematics', '--xacro-args', 'hand')
            self.assertEqual(code, 2)
            self.assertIn('name:=value', err)
        finally:
            os.environ['ROS_PACKAGE_PATH'] = saved
        code, lines, err = check_fk(arm, 'robot_ai/forward_kinematics')      # the package is gone from the path
        self.assertEqual(code, 2, lines)
        self.assertIn('package my_arm_description not found: put it on ROS_PACKAGE_PATH', err)
        self.assertEqual(len(err.strip().splitlines()), 1, err)

    def test_a_floating_base_is_graded_relative_to_its_body(self):
        """Issue 25: below a floating joint (a humanoid's pelvis, a mobile base) every link is graded relative to the
        joint's child: robot_state_publisher (which publishes body -> arm only), forward_kinematics and a course node
        (which publishes world -> odom -> body -> arm) pass in the time of any robot; a wrong one fails naming arm."""
        floating = os.path.join(HERE, 'urdf', 'floating_base_arm.urdf')
        for candidate in ('robot_state_publisher/robot_state_publisher', 'robot_ai/forward_kinematics',
                          'robot_ai/course_fk.py'):
            t = time.time()
            lines = self.assert_verdict(floating, candidate, 0, 'PASS', '--configurations', '10', mistake='none')
            self.assertLess(time.time() - t, 40.0, candidate)
            self.assertIn('score: 1/1 links, 10/10 configurations', lines)
            self.assertTrue(any('graded relative to body' in l for l in lines), lines)
        self.assert_verdict(floating, 'robot_ai/course_fk.py', 1, 'FAIL: arm, position off', '--configurations', '5',
                            mistake='order')

    def test_nothing_is_left_behind(self):
        """SIGTERM (what `timeout` sends) while check_fk runs a roscore of its own, and a candidate's child that
        ignores SIGINT: no process of the grade survives it, and no parameter stays on the master."""
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        mark = 'check_fk_orphan_%d' % os.getpid()
        port = free_port()
        env = dict(os.environ, ROS_MASTER_URI='http://127.0.0.1:%d' % port, COURSE_FK_MISTAKE='orphan',
                   COURSE_FK_MARK=mark)
        proc = subprocess.Popen(['rosrun', 'robot_ai', 'check_fk', '--model', kuka, '--candidate',
                                 'robot_ai/course_fk.py'], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        deadline = time.time() + 30
        while not processes(mark) and time.time() < deadline:
            time.sleep(0.2)
        self.assertTrue(processes(mark), 'the candidate did not start its child')
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=30)
        time.sleep(1.0)
        self.assertEqual(processes(mark), [])
        self.assertEqual(processes(str(port)), [])        # its roscore, rosmaster and rosout
        self.assertEqual(processes('__ns:=/check_fk_%d' % proc.pid), [])
        # a candidate that exits while its child keeps its output open: a verdict at once, and the child is gone
        t = time.time()
        code, lines, _ = check_fk(kuka, 'robot_ai/course_fk.py', mistake='abandon', mark=mark)
        self.assertEqual(code, 1)
        self.assertIn('FAIL: the candidate node exited with status 3', '\n'.join(lines))
        self.assertIn('leaving my child behind', '\n'.join(lines))
        self.assertLess(time.time() - t, 30)
        time.sleep(1.0)
        self.assertEqual(processes(mark), [])
        # on a shared master (rostest's), a finished grade leaves no /check_fk_<pid> parameters
        code, _, _ = check_fk(kuka, 'robot_ai/course_fk.py', '--configurations', '3', mistake='none')
        self.assertEqual(code, 0)
        names = subprocess.run(['rosparam', 'list'], capture_output=True, text=True, timeout=30).stdout.split()
        self.assertEqual([n for n in names if n.startswith('/check_fk_')], [])

    def test_nothing_is_left_behind_however_it_is_stopped(self):
        """Issue 23: a second SIGINT or SIGTERM during the clean-up, or a SIGHUP (the terminal closed), left the
        candidate, its child (both ignoring SIGINT) and the parameters on the master, and a double SIGINT printed a
        traceback; a grandchild that double-forked into its own session outlived even a normal FAIL."""
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        for signals in ((signal.SIGINT, signal.SIGINT), (signal.SIGTERM, signal.SIGTERM), (signal.SIGHUP,),
                        (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)):
            mark = 'check_fk_stubborn_%d_%d' % (os.getpid(), signals[0])
            env = dict(os.environ, COURSE_FK_MISTAKE='stubborn', COURSE_FK_MARK=mark)   # rostest's master
            proc = subprocess.Popen(['rosrun', 'robot_ai', 'check_fk', '--model', kuka, '--candidate',
                                     'robot_ai/course_fk.py', '--configurations', '200'], env=env,
                                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
            deadline = time.time() + 60
            while len(processes(mark)) < 2 and time.time() < deadline:
                time.sleep(0.2)
            self.assertGreaterEqual(len(processes(mark)), 2, 'the candidate did not start its children')
            time.sleep(1.0)
            for sig in signals:
                proc.send_signal(sig)
                time.sleep(0.5)          # the next one arrives while check_fk waits for its SIGINT-proof candidate
            out, _ = proc.communicate(timeout=60)
            time.sleep(0.5)
            text = out.decode(errors='replace')
            self.assertNotIn('Traceback', text, text[-2000:])
            self.assertEqual(processes(mark), [], signals)
            names = subprocess.run(['rosparam', 'list'], capture_output=True, text=True, timeout=30).stdout.split()
            self.assertEqual([n for n in names if n.startswith('/check_fk_')], [], signals)
            self.assertNotIn('/robot_description', names, signals)
        # a normal verdict: the escaped grandchild is gone too
        mark = 'check_fk_escape_%d' % os.getpid()
        code, lines, _ = check_fk(kuka, 'robot_ai/course_fk.py', '--configurations', '3', mistake='escape',
                                  mark=mark)
        self.assertEqual(code, 0, lines)
        time.sleep(0.5)
        self.assertEqual(processes(mark), [])

    def test_a_gigabyte_without_a_newline_keeps_memory_bounded(self):
        """A candidate writing 1 GiB without a newline raised check_fk to 1.24 GB: its output is read in pieces."""
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        env = dict(os.environ, COURSE_FK_MISTAKE='bigline')
        proc = subprocess.Popen(['rosrun', 'robot_ai', 'check_fk', '--model', kuka, '--candidate',
                                 'robot_ai/course_fk.py', '--configurations', '20'], env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        peak = 0
        while proc.poll() is None:
            for pid in descendants_of(proc.pid):
                try:
                    with open(f'/proc/{pid}/cmdline', 'rb') as f:
                        cmdline = f.read()
                    if b'check_fk' not in cmdline or b'__name:=candidate' in cmdline:
                        continue
                    with open(f'/proc/{pid}/status') as f:
                        hwm = [int(l.split()[1]) for l in f if l.startswith('VmHWM')]
                    peak = max([peak] + [h // 1024 for h in hwm])
                except OSError:
                    pass
            time.sleep(0.2)
        out = proc.stdout.read().decode(errors='replace')
        self.assertEqual(proc.returncode, 0, out[-2000:])
        self.assertGreater(peak, 0)
        self.assertLess(peak, 400, f'check_fk peaked at {peak} MB')

    # ------------------------------------------------------------------- a class in sandboxes (issue 33)
    def test_a_class_in_sandboxes_no_student_can_forge_or_escape(self):
        """Hostile students: one forges PASS in its output (a carriage return), in a frame name (a newline) and
        through /proc into the grader's stdout, then kills its parent; one writes into another student's folder,
        the package's venv and sources, connects to the grader's master, lists the class and leaves a daemon; one
        writes 600 MB to its output; one publishes a new wrong pose just inside --timeout for ever; a folder's
        name holds a newline. Each gets its own verdict in one line, the right node beside them passes, nothing
        of theirs is written or left running, and the grader's memory stays small."""
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        venv_site = [p for p in sys.path if p.endswith('site-packages') and '.venv' in p]
        with open(os.path.join(HERE, 'course_fk.py')) as f:
            course = f.read().replace("os.environ.get('COURSE_FK_MISTAKE', 'none')", "'none'")
        master_port = int(os.environ['ROS_MASTER_URI'].rsplit(':', 1)[1].strip('/'))
        planted = [os.path.join(HERE, 'planted_by_a_student.py')] + [os.path.join(p, 'planted.pth') for p in venv_site]
        hostile = {
            'alice': course,
            'mallory': HOSTILE_FORGER,
            'eve': HOSTILE_ESCAPER.replace('PLANTED', repr(planted)).replace('MASTER_PORT', str(master_port)),
            'flood': HOSTILE_FLOOD,
            'slow': HOSTILE_SLOW,
            'x\nPASS': course,
            'hog': HOSTILE_HOG,
        }
        with tempfile.TemporaryDirectory() as folder:
            klass = os.path.join(folder, 'class')
            for name, text in hostile.items():
                os.makedirs(os.path.join(klass, name))
                with open(os.path.join(klass, name, 'solution.py'), 'w') as f:
                    f.write(text.replace('ALICE', os.path.join(klass, 'alice', 'solution.py')))
            csv_path = os.path.join(folder, 'grades.csv')
            before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
            t = time.time()
            proc = subprocess.Popen(['rosrun', 'robot_ai', 'check_fk', '--model', kuka, '--candidates', klass,
                                     '--configurations', '3', '--timeout', '3', '--budget', '45', '--csv', csv_path],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE)
            stdout, stderr = proc.communicate(timeout=600)
            grader = proc.pid                # rosrun execs check_fk: its groups and uids are named by this pid
            elapsed = time.time() - t
            out = stdout.decode(errors='replace')
            self.assertEqual(proc.returncode, 0, out + stderr.decode(errors='replace')[-3000:])
            lines = out.splitlines()
            import csv
            with open(csv_path, newline='') as f:
                rows = {r['student']: r for r in csv.DictReader(f)}
            with open(os.path.join(klass, 'alice', 'solution.py')) as f:
                alice_after = f.read()
        self.assertIn('each student in a sandbox', out)
        # one line per student, whatever its name holds; the only PASS lines are alice's and the newline folder's
        self.assertEqual(sorted(rows), sorted(['alice', 'mallory', 'eve', 'flood', 'slow', 'x\\nPASS', 'hog']))
        self.assertEqual([l for l in lines if l.startswith('PASS')], [])
        self.assertEqual(rows['alice']['verdict'], 'PASS')
        self.assertEqual(rows['x\\nPASS']['verdict'], 'PASS')
        for name in ('mallory', 'eve', 'flood', 'slow', 'hog'):
            self.assertTrue(rows[name]['verdict'].startswith('FAIL: '), rows[name])
            self.assertNotIn('\n', rows[name]['verdict'])
            self.assertEqual(len([l for l in lines if l.startswith(name + ': FAIL')]), 1, (name, lines))
        self.assertTrue(rows['slow']['verdict'].startswith('FAIL: too slow ('), rows['slow'])
        self.assertIn('within the budget of 45 s, --budget', rows['slow']['verdict'])
        # issue 40: the hog's 60 busy loops, each in a session of its own, are its own group's: the right nodes beside
        # it still PASS (above), the class is told so, and no group is left behind
        self.assertIn('each student and its judge in a control group of their own', out)
        for hierarchy in ('cpu', 'memory', 'pids', 'unified'):   # this run's (another class may be graded meanwhile)
            folder = f'/sys/fs/cgroup/{hierarchy}/robot_ai_grading'
            left = [d for d in os.listdir(folder) if d.startswith(f'check_fk_{grader}_')] \
                if os.path.isdir(folder) else []
            self.assertEqual(left, [], hierarchy)
        self.assertLess(elapsed, 300)
        # nothing written where the student must not write, nothing of theirs left running
        self.assertEqual(alice_after, course)
        for path in planted:
            self.assertFalse(os.path.exists(path), path)
        leftover = subprocess.run(['ps', '-eo', 'uid=,args='], capture_output=True, text=True).stdout.splitlines()
        theirs = {sandbox.uid_for(grader, i) for i in range(len(hostile))}
        self.assertEqual([l for l in leftover if int(l.split()[0]) % 2 ** 32 in theirs], [])   # ps: signed uids
        # the grader's memory: the 600 MB of output never were in it
        peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        self.assertLess(max(peak, before) // 1024, 600, f'a process of the class run peaked at {peak // 1024} MB')

    def test_a_grader_killed_with_sigkill_loses_no_verdict_and_leaves_nothing_running(self):
        """Issue 56: a class run killed with SIGKILL (an out-of-memory kill) mid-class: its CSV holds the header and
        every verdict it printed; its judges, their roscores and their students end within seconds, not grading on
        for nobody; the next class run removes the work folder and control groups it left."""
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        with open(os.path.join(HERE, 'course_fk.py')) as f:
            course = f.read()
        default = "os.environ.get('COURSE_FK_MISTAKE', 'none')"
        students = {'a_fast': course.replace(default, "'none'"), 'b_fast': course.replace(default, "'none'"),
                    'c_slow': course.replace(default, "'sleep'"), 'd_slow': course.replace(default, "'sleep'")}
        with tempfile.TemporaryDirectory() as folder:
            klass = os.path.join(folder, 'class')
            for name, text in students.items():
                os.makedirs(os.path.join(klass, name))
                with open(os.path.join(klass, name, 'fk.py'), 'w') as f:
                    f.write(text.replace("float(os.environ.get('COURSE_FK_SLEEP', '0.1'))", '2.0'))
            csv_path = os.path.join(folder, 'grades.csv')
            proc = subprocess.Popen(['rosrun', 'robot_ai', 'check_fk', '--model', kuka, '--candidates', klass,
                                     '--configurations', '10', '--jobs', '2', '--csv', csv_path],
                                    stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            grader = proc.pid
            printed, deadline = [], time.time() + 400
            while not printed and time.time() < deadline:
                line = proc.stdout.readline()
                if not line:
                    break
                if line.split(':')[0] in students:
                    printed.append(line.strip())
            self.assertTrue(printed, 'no student was graded')
            mine = {sandbox.uid_for(grader, i) for i in range(len(students))}
            t = time.time()                        # the slow students' judges start them
            while not processes_of_uids(mine) and time.time() - t < 120:
                time.sleep(0.2)
            before = processes_of_uids(mine)
            proc.kill()
            proc.wait()
            import csv
            with open(csv_path, newline='') as f:
                rows = list(csv.DictReader(f))
            self.assertGreaterEqual(len(rows), len(printed), rows)
            for line in printed:
                name = line.split(':')[0]
                self.assertTrue(any(r['student'] == name and line.startswith(f"{name}: {r['verdict']}")
                                    for r in rows), (line, rows))
            self.assertTrue(before, 'no student was running when the grader was killed: the test is wrong')
            t = time.time()
            while processes_of_uids(mine) and time.time() - t < 30:
                time.sleep(0.2)
            self.assertEqual(processes_of_uids(mine), [], 'the killed grader\'s students go on')
            self.assertEqual([l for l in processes_matching(klass)], [], 'its judges go on')
            left = glob.glob(f'/tmp/check_fk_class_{grader}_*')
            self.assertTrue(left, 'the killed run left no work folder: the test is wrong')
            # the next run (a class of one) removes what the killed one left
            os.makedirs(os.path.join(folder, 'next', 'alice'))
            with open(os.path.join(folder, 'next', 'alice', 'fk.py'), 'w') as f:
                f.write(students['a_fast'])
            done = subprocess.run(['rosrun', 'robot_ai', 'check_fk', '--model', kuka, '--candidates',
                                   os.path.join(folder, 'next'), '--configurations', '3',
                                   '--csv', os.path.join(folder, 'next.csv')], capture_output=True, text=True,
                                  timeout=600)
            self.assertEqual(done.returncode, 0, done.stdout[-2000:] + done.stderr[-2000:])
            self.assertEqual(glob.glob(f'/tmp/check_fk_class_{grader}_*'), [])
            for hierarchy in ('cpu', 'memory', 'pids', 'unified'):
                groups = f'/sys/fs/cgroup/{hierarchy}/robot_ai_grading'
                if os.path.isdir(groups):
                    self.assertEqual([d for d in os.listdir(groups) if d.startswith(f'check_fk_{grader}_')], [])

    def test_grades_in_the_columns_moodle_and_canvas_import(self):
        """Issue 56: Moodle's download (a folder per student, `Full Name_N_assignsubmission_file_`) graded into
        Moodle's grading worksheet, Canvas's (one file per student, `lastfirst_N_M_name.py`) into Canvas's gradebook
        import; a student that stores a gigabyte of parameters in its judge's master is refused and named."""
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        with open(os.path.join(HERE, 'course_fk.py')) as f:
            course = f.read()
        default = "os.environ.get('COURSE_FK_MISTAKE', 'none')"
        import csv
        with tempfile.TemporaryDirectory() as folder:
            moodle = os.path.join(folder, 'moodle')
            for name, text in (('Jane Doe_1001_assignsubmission_file_', course.replace(default, "'none'")),
                               ('Bob Roe_1002_assignsubmission_file_', course.replace(default, "'first'")),
                               ('Max Hog_1003_assignsubmission_file_', HOSTILE_PARAMETERS)):
                os.makedirs(os.path.join(moodle, name))
                with open(os.path.join(moodle, name, 'fk_node.py'), 'w') as f:
                    f.write(text)
            proc = subprocess.run(['rosrun', 'robot_ai', 'check_fk', '--model', kuka, '--candidates', moodle,
                                   '--configurations', '3', '--csv-format', 'moodle',
                                   '--csv', os.path.join(folder, 'moodle.csv')], capture_output=True, text=True,
                                  timeout=600)
            self.assertEqual(proc.returncode, 0, proc.stdout[-3000:] + proc.stderr[-2000:])
            with open(os.path.join(folder, 'moodle.csv'), newline='') as f:
                rows = list(csv.reader(f))
            self.assertEqual(rows[0], ['Identifier', 'Full name', 'Grade', 'Maximum Grade', 'Feedback comments'])
            by_id = {r[0]: r for r in rows[1:]}
            self.assertEqual(sorted(by_id), ['Participant 1001', 'Participant 1002', 'Participant 1003'])
            self.assertEqual(by_id['Participant 1001'][1:4], ['Jane Doe', '100.0', '100'])
            self.assertTrue(0 < float(by_id['Participant 1002'][2]) < 100, by_id)
            self.assertTrue(by_id['Participant 1002'][4].startswith('FAIL: lwr_arm_1_link'), by_id)
            self.assertIn('asked its master to hold more than 64 MiB of parameters', by_id['Participant 1003'][4])
            canvas = os.path.join(folder, 'canvas')
            os.makedirs(canvas)
            for name, text in (('doejane_2001_777_fk.py', course.replace(default, "'none'")),
                               ('roebob_LATE_2002_778_fk.py', course.replace(default, "'first'"))):
                with open(os.path.join(canvas, name), 'w') as f:
                    f.write(text)
            proc = subprocess.run(['rosrun', 'robot_ai', 'check_fk', '--model', kuka, '--candidates', canvas,
                                   '--configurations', '3', '--csv-format', 'canvas', '--id-from', 'file',
                                   '--assignment', 'FK node (4711)', '--csv', os.path.join(folder, 'canvas.csv')],
                                  capture_output=True, text=True, timeout=600)
            self.assertEqual(proc.returncode, 0, proc.stdout[-3000:] + proc.stderr[-2000:])
            with open(os.path.join(folder, 'canvas.csv'), newline='') as f:
                rows = list(csv.reader(f))
        self.assertEqual(rows[0], ['Student', 'ID', 'SIS User ID', 'SIS Login ID', 'Section', 'FK node (4711)'])
        by_id = {r[1]: r for r in rows[1:]}
        self.assertEqual(by_id['2001'][0], 'doejane')
        self.assertEqual(by_id['2001'][5], '100.0')
        self.assertTrue(0 < float(by_id['2002'][5]) < 100, by_id)

    def test_every_option_reaches_every_student_and_the_header_says_what_is_graded(self):
        """--xacro-args reach each student's check (the reference and the robot_description are the xacro's with
        them: 10 links graded with the tool, the root's 11 in all; 9 without), and the class header names the model
        and its arguments; a --candidate file that is neither Python nor executable is one line; `--xacro-args
        "a:=1 b:=2"` with a single candidate is no traceback."""
        arm7 = os.path.join(HERE, 'urdf', 'reach_arm7.urdf.xacro')
        with open(os.path.join(HERE, 'course_fk.py')) as f:
            course = f.read().replace("os.environ.get('COURSE_FK_MISTAKE', 'none')", "'none'")
        with tempfile.TemporaryDirectory() as folder:
            os.makedirs(os.path.join(folder, 'class', 'ann'))
            with open(os.path.join(folder, 'class', 'ann', 'fk.py'), 'w') as f:
                f.write(course)
            csv_path = os.path.join(folder, 'grades.csv')
            proc = subprocess.run(['rosrun', 'robot_ai', 'check_fk', '--model', arm7, '--xacro-args',
                                   'scale:=2 tool:=true', '--candidates', os.path.join(folder, 'class'),
                                   '--configurations', '3', '--csv', csv_path], capture_output=True, text=True,
                                  timeout=300)
            self.assertEqual(proc.returncode, 0, proc.stdout + proc.stderr)
            self.assertIn(f'on {arm7} with xacro arguments "scale:=2 tool:=true" (11 links)', proc.stdout)
            self.assertIn('ann: PASS [10/10 links, 3/3 configurations]', proc.stdout)
            text = os.path.join(folder, 'notes.txt')
            with open(text, 'w') as f:
                f.write('my answer is in the pdf\n')
            code, lines, err = check_fk(arm7, text, '--xacro-args', 'scale:=2 tool:=true')
            self.assertEqual(code, 1)
            self.assertEqual(lines[-1], 'FAIL: notes.txt is neither a Python file (.py, or a #! line naming python) '
                                        'nor executable: the node cannot start')
            self.assertNotIn('Traceback', err)
        code, lines, err = check_fk(arm7, 'robot_ai/forward_kinematics', '--xacro-args', 'scale:=2 tool:=true',
                                    '--configurations', '3')
        self.assertEqual(code, 0, '\n'.join(lines) + err)
        self.assertNotIn('Traceback', err)
        self.assertIn('score: 10/10 links, 3/3 configurations', lines)

    def test_a_single_candidate_in_a_sandbox_and_its_budget(self):
        """--candidate with --sandbox: the node runs as a user of its own in a network of its own (the grader's
        master out of reach) and passes as it does outside; a node that answers just inside --timeout with a new
        wrong pose each time is ended by --budget with a verdict that says so."""
        kuka = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
        with tempfile.TemporaryDirectory() as folder:
            right = os.path.join(folder, 'right.py')
            with open(os.path.join(HERE, 'course_fk.py')) as f, open(right, 'w') as g:
                g.write(f.read().replace("os.environ.get('COURSE_FK_MISTAKE', 'none')", "'none'"))
            code, lines, err = check_fk(kuka, right, '--sandbox', '--configurations', '3')
            self.assertEqual(code, 0, '\n'.join(lines) + err[-2000:])
            self.assertEqual(lines[-1], 'PASS')
            self.assertTrue(any(l.startswith(f'check_fk: {right} on') for l in lines), lines)   # the user's path
            slow = os.path.join(folder, 'slow.py')
            with open(slow, 'w') as f:
                f.write(HOSTILE_SLOW)
            t = time.time()
            code, lines, err = check_fk(kuka, slow, '--budget', '25', '--timeout', '3')
            self.assertEqual(code, 1, '\n'.join(lines) + err[-2000:])
            self.assertTrue(lines[-1].startswith('FAIL: too slow (') and 'the budget of 25 s, --budget)' in lines[-1],
                            lines[-1])
            self.assertLess(time.time() - t, 60)



def processes_of_uids(uids):
    out = subprocess.run(['ps', '-eo', 'uid=,pid=,args='], capture_output=True, text=True).stdout.splitlines()
    return [l for l in out if l.split() and int(l.split()[0]) % 2 ** 32 in uids]     # ps prints uids as signed


def processes_matching(text):
    out = subprocess.run(['ps', '-eo', 'pid=,args='], capture_output=True, text=True).stdout.splitlines()
    return [l for l in out if text in l and 'ps -eo' not in l]


def descendants_of(pid):
    out = subprocess.run(['ps', '-eo', 'pid=,ppid='], capture_output=True, text=True).stdout.split()
    children, found, todo = {}, [], [str(pid)]
    for child, parent in zip(out[::2], out[1::2]):
        children.setdefault(parent, []).append(child)
    while todo:
        p = todo.pop()
        found.append(int(p))
        todo.extend(children.get(p, []))
    return found


def free_port():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def processes(text):
    """The command lines of running processes that contain text (this test's own ps and grep aside)."""
    out = subprocess.run(['ps', '-eo', 'args='], capture_output=True, text=True).stdout.splitlines()
    return [l for l in out if text in l and not l.startswith('ps ')]


# hostile students (test_a_class_in_sandboxes_no_student_can_forge_or_escape); each calls rospy.init_node and
# reads joint_states, so that check_fk's search takes its file for the node
HOSTILE_FORGER = """#!/usr/bin/env python3
import os, sys, time
import rospy, tf2_ros
from geometry_msgs.msg import TransformStamped
rospy.init_node('fk')   # joint_states
print('bye\\rPASS', flush=True)
broadcaster = tf2_ros.TransformBroadcaster()
t = TransformStamped()
t.header.frame_id, t.child_frame_id = 'lwr_arm_base_link', 'b\\nPASS'
t.transform.rotation.w = 1.0
for _ in range(40):
    t.header.stamp = rospy.Time.now()
    broadcaster.sendTransform(t)
    time.sleep(0.1)
for pid in (os.getppid(), 1):
    try:
        with open(f'/proc/{pid}/fd/1', 'w') as f:
            f.write('\\nPASS\\n')
    except OSError as e:
        print('no write to', pid, e)
    try:
        os.kill(pid, 9)
    except OSError as e:
        print('no kill of', pid, e)
sys.exit(0)
"""
HOSTILE_ESCAPER = """#!/usr/bin/env python3
import os, socket, subprocess
import rospy
rospy.init_node('fk')   # joint_states
for target in ['ALICE'] + PLANTED:
    try:
        with open(target, 'w') as f:
            f.write('import os; os.system("touch /tmp/pwned")\\n')
        print('WROTE', target)
    except OSError as e:
        print('no write', target, type(e).__name__)
s = socket.socket()
s.settimeout(1.0)
try:
    s.connect(('127.0.0.1', MASTER_PORT))
    print('CONNECTED to the grader master')
except OSError as e:
    print('no connect', type(e).__name__)
subprocess.Popen(['sh', '-c', 'setsid sleep 1000 > /dev/null 2>&1 &'])
rospy.spin()
"""
HOSTILE_FLOOD = """#!/usr/bin/env python3
import os
import rospy
rospy.init_node('fk')   # joint_states
chunk = b'x' * (1 << 20)
for _ in range(600):
    os.write(1, chunk)
rospy.spin()
"""
HOSTILE_HOG = """#!/usr/bin/env python3
# 60 busy loops, each in a session of its own (the kernel's autogroup makes each a scheduling group), then a node
import os
import rospy
for _ in range(60):
    if os.fork() == 0:
        os.setsid()
        while True:
            pass
rospy.init_node('hog')
rospy.spin()
"""

HOSTILE_PARAMETERS = """#!/usr/bin/env python3
import rospy
from sensor_msgs.msg import JointState
rospy.init_node('fk')   # joint_states
for i in range(120):    # 1,200 MiB of parameters in its judge's master
    try:
        rospy.set_param('/junk/%d' % i, 'x' * (10 * 1024 * 1024))
    except Exception as e:
        print('refused after', i, e)
        break
rospy.spin()
"""

HOSTILE_SLOW = """#!/usr/bin/env python3
import time
import rospy, tf2_ros
from geometry_msgs.msg import TransformStamped
rospy.init_node('fk')   # joint_states
broadcaster = tf2_ros.TransformBroadcaster()
i = 0
while not rospy.is_shutdown():     # a new wrong pose every 2.5 s, just inside --timeout 3
    i += 1
    t = TransformStamped()
    t.header.stamp = rospy.Time.now()
    t.header.frame_id, t.child_frame_id = 'lwr_arm_base_link', 'lwr_arm_1_link'
    t.transform.translation.x = float(i)
    t.transform.rotation.w = 1.0
    broadcaster.sendTransform(t)
    time.sleep(2.5)
"""

# The class cases (a class at once, in sandboxes, every option reaching every student, a sandboxed candidate) run as
# check_fk_class.test, the others as check_fk.test: make test runs the two side by side (each case alone in either).
CLASS_CASES = ('test_a_class_at_once', 'test_a_class_in_sandboxes_no_student_can_forge_or_escape',
               'test_every_option_reaches_every_student_and_the_header_says_what_is_graded',
               'test_a_single_candidate_in_a_sandbox_and_its_budget',
               'test_a_grader_killed_with_sigkill_loses_no_verdict_and_leaves_nothing_running',
               'test_grades_in_the_columns_moodle_and_canvas_import')


if __name__ == '__main__':
    classes = 'classes' in sys.argv[1:]
    rostest.rosrun('robot_ai', 'test_check_fk_class' if classes else 'test_check_fk',
                   cases_of(TestCheckFk, CLASS_CASES, classes, 'TestCheckFkClasses' if classes else 'TestCheckFkNodes'))
