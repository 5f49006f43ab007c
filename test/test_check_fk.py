#!/usr/bin/env python3
"""check_fk as a student runs it: it passes robot_state_publisher and forward_kinematics on every reference robot,
fails a node that rotates by euler angles axis * q on a URDF with a tilted axis (naming the link), passes that
same node where every axis is along x, y or z, and gives a clear verdict for a node that crashes or stays silent."""
import glob
import os
import resource
import signal
import socket
import subprocess
import sys
import tempfile
import time
import unittest

import rostest

sys.path.insert(0, os.path.dirname(os.path.realpath(__file__)))
from fk_helpers import ROBOTS_DIR, write_xacro_package  # noqa: E402

HERE = os.path.dirname(os.path.realpath(__file__))
TILTED = os.path.join(HERE, 'urdf', 'tilted_axis_arm.urdf')
ROBOTS = sorted(glob.glob(os.path.join(ROBOTS_DIR, '*.urdf')) + glob.glob(os.path.join(ROBOTS_DIR, 'fixtures', '*.urdf')))


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
                     'FAIL: solution.py line 5 is Python 2 (except X, e): ROS Noetic runs Python 3; write except X as e'),
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
        setter = subprocess.run([sys.executable, '-c', 'import rospy, sys; rospy.set_param("/grader/robot_description", '
                                 'sys.stdin.read())'], input=xml, text=True, capture_output=True, timeout=60)
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
                    'erin': open(os.path.join(HERE, 'silent_fk.py')).read(), 'frank': None}
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
        self.assertEqual(sorted(rows), sorted(students))
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
        self.assertIn('1 of 6 PASS', proc.stdout)

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


if __name__ == '__main__':
    rostest.rosrun('robot_ai', 'test_check_fk', TestCheckFk)
