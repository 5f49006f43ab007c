#!/usr/bin/env python3
"""The package on a Ray cluster of two nodes on this machine (ray.cluster_utils.Cluster: a head that runs nothing
and two raylets of one CPU each), against the same work done here: check_fk grades a class of correct, wrong and
hostile students into the local run's CSV and reports, also when a node is killed mid-class; the Q-learning
learners and ARS's rollouts give the local numbers bit for bit. Skipped, saying why, where Ray is not installed
(make test installs it: requirements-ray.txt)."""
import csv
import glob
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
import unittest

import numpy as np
import rostest

sys.path.insert(0, os.path.dirname(os.path.realpath(__file__)))
from fk_helpers import ROBOTS_DIR  # noqa: E402
from test_check_fk import HOSTILE_FORGER  # noqa: E402

from robot_ai import fleet  # noqa: E402
from robot_ai.grading import on_ray  # noqa: E402

HERE = os.path.dirname(os.path.realpath(__file__))
KUKA = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
UR5 = os.path.join(ROBOTS_DIR, 'ur5.urdf')
SLOW_RIGHT = """#!/usr/bin/env python3
# the course's node (rospy.init_node, joint_states) after a slow start: its task is running when its node is killed
import time
time.sleep(SECONDS)
exec(compile(open('/student/solution.txt').read(), 'solution.txt', 'exec'), {'__name__': '__main__'})
"""


def read_csv(path: str) -> list[dict]:
    with open(path, newline='') as f:
        return list(csv.DictReader(f))


def without_seconds(rows: list[dict]) -> list[tuple]:
    return [(r['student'], r['verdict'], r['score'], r['first_wrong_link']) for r in rows]


def report_text(path: str) -> str:
    """A report with its times and its judge's temporary paths taken out: what must equal the local run's."""
    with open(path, errors='replace') as f:
        text = f.read()
    text = re.sub(r'\d+\.\d+ s\b', 'X s', text)
    return re.sub(r'/tmp/check_fk_judge_\w+', '/tmp/check_fk_judge_X', text)


class TestRayCluster(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        problem = fleet.available()
        if problem:
            raise unittest.SkipTest(problem)
        os.environ['RAY_USAGE_STATS_ENABLED'] = '0'
        from ray.cluster_utils import Cluster
        cls.cluster = Cluster(initialize_head=True, head_node_args={'num_cpus': 0})
        cls.nodes = [cls.cluster.add_node(num_cpus=1) for _ in range(2)]
        cls.cluster.wait_for_nodes()
        cls.address = cls.cluster.address

    def ray(self):
        return fleet.connect(self.address)

    @classmethod
    def tearDownClass(cls):
        import ray
        if ray.is_initialized():
            ray.shutdown()
        cls.cluster.shutdown()

    # ----------------------------------------------------------------------------------------- learners
    def test_1_q_learning_learners_on_ray_equal_the_local_pool(self):
        from robot_ai.cartpole import q_learning
        training = q_learning.resolve('CartPole-v0', 30, 0.99, 'sgd', 50, 3, False)
        local = q_learning.train(training, seed=5, workers=2)
        seen = []
        on_ray = q_learning.train(training, seed=5, ray_address=self.address,
                                  progress=lambda j, e, r, eps: seen.append((j, e)))
        self.assertEqual(on_ray.finished, [0, 1, 2])
        self.assertEqual(on_ray.failed, {})
        for j in range(3):
            np.testing.assert_array_equal(on_ray.total_rewards[j], local.total_rewards[j])
            np.testing.assert_array_equal(on_ray.agents[j].q_weights, local.agents[j].q_weights)
            np.testing.assert_array_equal(on_ray.agents[j].feature_weights, local.agents[j].feature_weights)
        np.testing.assert_array_equal(on_ray.greedy_averages, local.greedy_averages)
        # every episode of every learner reported, each learner's in order
        self.assertEqual(sorted(seen), [(j, e) for j in range(3) for e in range(1, 31)])
        for j in range(3):
            self.assertEqual([e for k, e in seen if k == j], list(range(1, 31)))

    def test_2_ars_rollouts_on_ray_equal_the_local_run(self):
        from dataclasses import replace

        from robot_ai.cartpole import linear_search
        from robot_ai.reach import learn
        kwargs = dict(model=UR5)
        settings = replace(learn.default_settings(learn.ReachSetup(**kwargs)), iterations=5)

        def reach(**k):
            r = learn.train(kwargs, settings, seed=3, evaluate_episodes=0, **k).result
            return r.last_policy.weights, [h.rollout_return for h in r.history], r.steps
        # from home: one env here, two actors there, the same numbers
        here, there = reach(), reach(ray_address=self.address)
        np.testing.assert_array_equal(here[0], there[0])
        self.assertEqual(here[1:], there[1:])
        # chained (each arm goes on from where it stopped): the same two chunks here and there
        kwargs['start'] = 'chained'
        here, there = reach(chunks=2), reach(chunks=2, ray_address=self.address)
        np.testing.assert_array_equal(here[0], there[0])
        self.assertEqual(here[1:], there[1:])
        # the course's CartPole: gymnasium's vector env, the same chunks
        short = replace(linear_search.ARS_SETTINGS, iterations=8)
        here = linear_search.ars_search('CartPole-v1', 1, short, chunks=2)
        there = linear_search.ars_search('CartPole-v1', 1, short, chunks=2, ray_address=self.address)
        np.testing.assert_array_equal(here.last_policy.weights, there.last_policy.weights)
        self.assertEqual(here.steps, there.steps)

    # ----------------------------------------------------------------------------------------- a class
    def write_class(self, folder: str) -> str:
        """A class: right nodes (one of them slow to start, one in a folder whose name holds a newline), a wrong one,
        a forger, a folder with no node and one too large to copy."""
        with open(os.path.join(HERE, 'course_fk.py')) as f:
            course = f.read()
        right = course.replace("os.environ.get('COURSE_FK_MISTAKE', 'none')", "'none'")
        wrong = course.replace("os.environ.get('COURSE_FK_MISTAKE', 'none')", "'first'")
        klass = os.path.join(folder, 'class')
        files = {'alice': {'solution.py': right}, 'bob': {'solution.py': wrong}, 'mallory': {'fk.py': HOSTILE_FORGER},
                 'x\nPASS': {'solution.py': right}, 'nobody': {'notes.txt': 'no node here'},
                 'slow1': {'solution.py': SLOW_RIGHT.replace('SECONDS', '8'), 'solution.txt': right},
                 'slow2': {'solution.py': SLOW_RIGHT.replace('SECONDS', '8'), 'solution.txt': right}}
        for student, contents in files.items():
            os.makedirs(os.path.join(klass, student))
            for name, text in contents.items():
                with open(os.path.join(klass, student, name), 'w') as f:
                    f.write(text)
        crowd = os.path.join(klass, 'crowd')          # more files than the sandbox copies
        os.makedirs(crowd)
        for i in range(5001):
            open(os.path.join(crowd, f'{i}.txt'), 'w').close()
        return klass

    def grade(self, klass: str, csv_path: str, *extra: str, on_line=None) -> tuple[int, list[str]]:
        cmd = ['rosrun', 'robot_ai', 'check_fk', '--model', KUKA, '--candidates', klass, '--configurations', '3',
               '--timeout', '3', '--csv', csv_path] + list(extra)
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        lines = []
        timer = threading.Timer(600, proc.kill)
        timer.start()
        try:
            for line in proc.stdout:
                lines.append(line.rstrip('\n'))
                if on_line is not None:
                    on_line(line)
            return proc.wait(), lines
        finally:
            timer.cancel()

    def test_3_a_class_on_two_nodes_is_the_local_csv_even_when_a_node_dies(self):
        """The Ray run's CSV and reports equal the local run's (but for the seconds), with one of the two nodes
        killed while it grades: its student's task runs again on the other node, every student has one line, and
        no sandboxed process or control group is left behind."""
        with tempfile.TemporaryDirectory() as folder:
            klass = self.write_class(folder)
            local_csv, ray_csv = os.path.join(folder, 'local.csv'), os.path.join(folder, 'ray.csv')
            since = time.time()
            code, local_lines = self.grade(klass, local_csv, '--jobs', '2')
            self.assertEqual(code, 0, '\n'.join(local_lines))
            killed = []

            def kill_a_node(line: str) -> None:       # once the first verdict is in, a node goes (slow1 or slow2 on it)
                if not killed and re.match(r'^\S+: (PASS|FAIL)', line):
                    killed.append(time.time())
                    self.cluster.remove_node(self.nodes[0], allow_graceful=False)
            code, ray_lines = self.grade(klass, ray_csv, '--ray', self.address, on_line=kill_a_node)
            out = '\n'.join(ray_lines)
            self.assertEqual(code, 0, out)
            self.assertTrue(killed, out)
            self.assertIn('on the Ray cluster at', out)
            self.assertIn('each student in a sandbox', out)
            local, on_ray = read_csv(local_csv), read_csv(ray_csv)
            self.assertEqual(without_seconds(on_ray), without_seconds(local), out)
            verdicts = {r['student']: r['verdict'] for r in on_ray}
            for student in ('alice', 'x\\nPASS', 'slow1', 'slow2'):
                self.assertEqual(verdicts[student], 'PASS', (student, out))
            for student in ('bob', 'mallory', 'nobody', 'crowd'):
                self.assertTrue(verdicts[student].startswith('FAIL: '), (student, verdicts[student]))
            self.assertIn('cannot be graded', verdicts['crowd'])
            # one line per student, and no forged PASS line
            for student in ('alice', 'bob', 'mallory', 'nobody', 'crowd', 'slow1', 'slow2'):
                self.assertEqual(len([l for l in ray_lines if l.startswith(student + ': ')]), 1, (student, out))
            self.assertEqual([l for l in ray_lines if l.startswith('PASS')], [])
            # the reports: the same, but for times and the judge's temporary folder
            local_reports = sorted(os.listdir(os.path.join(folder, 'local_reports')))
            ray_reports = sorted(os.listdir(os.path.join(folder, 'ray_reports')))
            self.assertEqual(ray_reports, local_reports)
            for name in local_reports:
                self.assertEqual(report_text(os.path.join(folder, 'ray_reports', name)),
                                 report_text(os.path.join(folder, 'local_reports', name)), name)
            self.assert_nothing_left(klass, since)

    def test_4_a_signal_stops_the_class_and_writes_the_csv(self):
        """SIGINT once the first verdict is in: the tasks are cancelled (their judges with them), the CSV holds every
        student, those graded and the rest 'not graded (check_fk was stopped)', and nothing is left running."""
        if len(fleet.cluster_cpus(self.ray())) < 2:      # the node test_3 killed: another in its place
            self.nodes[0] = self.cluster.add_node(num_cpus=1)
            self.cluster.wait_for_nodes()
        with tempfile.TemporaryDirectory() as folder:
            klass = self.write_class(folder)
            ray_csv = os.path.join(folder, 'ray.csv')
            since = time.time()
            proc = subprocess.Popen(['rosrun', 'robot_ai', 'check_fk', '--model', KUKA, '--candidates', klass,
                                     '--configurations', '3', '--timeout', '3', '--csv', ray_csv, '--ray',
                                     self.address], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            # once the class is under way (its first verdict: connecting to the cluster takes seconds on a loaded
            # machine), while the slow students still sleep
            lines = []
            timer = threading.Timer(300, proc.kill)
            timer.start()
            try:
                for line in proc.stdout:
                    lines.append(line)
                    if re.match(r'^\S+: (PASS|FAIL)', line):
                        proc.send_signal(2)
                        break
                rest, _ = proc.communicate(timeout=120)
            finally:
                timer.cancel()
            out = ''.join(lines) + rest
            self.assertEqual(proc.returncode, 130, out)
            self.assertIn('check_fk: stopped:', out)
            rows = read_csv(ray_csv)
            self.assertEqual(len(rows), 8, out)
            self.assertTrue(any(r['verdict'] == 'not graded (check_fk was stopped)' for r in rows), out)
            self.assert_nothing_left(klass, since)
            self.assert_no_dead_workers_folder()

    def test_5_a_node_grades_the_model_it_is_sent_not_a_file_it_may_not_have(self):
        """A node of a real cluster need not have the model file (nor its xacro includes) at the grader's path: the
        task carries the expanded URDF, and the report names the model as the user gave it."""
        from robot_ai.grading import on_ray, sandbox
        from robot_ai.grading.class_run import ClassRun
        from robot_ai.grading.report import read_model
        from robot_ai.nodes.check_fk import parse_args
        with tempfile.TemporaryDirectory() as folder:
            klass = self.write_class(folder)
            a = parse_args(['--model', '/nowhere/on/the/node/arm.urdf.xacro', '--candidates', klass,
                            '--configurations', '3', '--timeout', '3'])
            run = ClassRun.of(a, read_model(KUKA)[1])
            xml = read_model(KUKA)[0]
            ray = self.ray()
            task = ray.remote(on_ray.grade_on_node).options(num_cpus=1)
            index = run.students.index('alice')
            alice = os.path.join(klass, 'alice')
            result, report = ray.get(task.remote(run.judging, index, 'alice', alice, sandbox.pack_folder(alice), 1.0,
                                                 xml), timeout=300)
        self.assertEqual(result.verdict, 'PASS', report.decode(errors='replace'))
        self.assertIn(f'check_fk: {alice}/solution.py on /nowhere/on/the/node/arm.urdf.xacro (', report.decode())

    def assert_nothing_left(self, klass: str, since: float) -> None:
        """No judge of this class runs (a judge's command names its student's folder; its students die with its
        namespaces), no control group outlives the process that made it (other tests' classes may be graded
        beside this one: theirs are alive), and no judge killed since `since` left the mount point of its logs in
        /tmp (judges make it in their grader's work folder)."""
        deadline = time.time() + 30
        while True:          # the killed node's judge ends with its worker (its death signal)
            left = [l for l in subprocess.run(['ps', '-eo', 'pid=,args='], capture_output=True,
                                              text=True).stdout.splitlines() if klass in l]
            if not left or time.time() > deadline:
                break
            time.sleep(0.5)
        self.assertEqual(left, [])
        for hierarchy in ('cpu', 'memory', 'pids', 'unified'):
            groups = f'/sys/fs/cgroup/{hierarchy}/robot_ai_grading'
            names = [d for d in os.listdir(groups) if d.startswith('check_fk_')] if os.path.isdir(groups) else []
            stale = [d for d in names if not os.path.exists(f'/proc/{d.split("_")[2]}')]
            self.assertEqual(stale, [], hierarchy)
        left = [d for d in glob.glob(os.path.join(tempfile.gettempdir(), 'check_fk_judge_*'))
                if os.path.getmtime(d) >= since]
        self.assertEqual(left, [])

    def assert_no_dead_workers_folder(self) -> None:
        """No task's work folder (a student's copy) of a worker that is gone: a task sweeps those of workers killed
        before their clean-up (test_3's node), and a cancelled task removes its own."""
        deadline = time.time() + 30
        while True:
            stale = on_ray.dead_workers_folders()
            if not stale or time.time() > deadline:
                break
            time.sleep(0.5)
        self.assertEqual(stale, [])


if __name__ == '__main__':
    rostest.rosrun('robot_ai', 'test_ray_cluster', TestRayCluster)
