#!/usr/bin/env python3
"""Run the package's tests side by side, longest first, each as catkin runs it (the rule of its `_run_tests_robot_ai_*`
target in the workspace's build folder, so the commands and the result files are catkin's own), and print a line as
each ends. The results folder is emptied once before (make test does it), never by a target.

    python test/run_tests.py --build .catkin_ws/build --jobs 4        # then test/summarize.py reads the results

Every rostest starts a master of its own on a free port, so rostests do not meet. The unit tests (pytest) run beside
them. A target's output goes to <build>/test_logs/<name>.log; a failed target's last lines are printed. Exits 0
(summarize.py decides): a test that fails is in its results file, a target that could not run is a MISSING result.
"""
import argparse
import concurrent.futures
import os
import pathlib
import subprocess
import sys
import threading
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
# measured on the 2-core machine with two busy loops (a fresh clone, 2026-12-03), seconds each took beside the others:
# launch 959, pytest 521, check_fk 520, launch_rviz 194, check_fk_class 189, cartpole_q_learning 113, policy_files
# 101, cartpole_robot 96, cartpole_search 85, across_machines 85, forward_kinematics_vs_rsp 83, ros_env 78, reach_ros
# 51, forward_kinematics_node 41, bench_output 26, the rest under 20 (reach_pose 161 s beside reach_ros and
# reach_safety; reach_safety 339 s on 2026-12-04). The longest start first, so that the run ends soon after its
# longest test; a .test file not named here runs after these, in name order. reach_safety.test and
# reach_safety_input.test are not named: they run after the others, side by side (one file until 2026-12-05: 215 s
# at the end of the run, nearly alone, the last 200 s of a quiet run's 933). Beside the long tests its commands
# reach arm_sim late: a jolt over an acceleration limit in 3 of 3 fresh-clone runs on 2026-12-03; on 2026-12-04,
# with arm_sim and reach_controller at nice -10
# (robot_ai.priority), ~load_policy between control steps and slow plans not sent, it passed one fresh-clone run
# beside them (the tests in 884 s) and failed the next: late too often, during whole-machine stalls of half a second.
# ray_cluster (117 s alone) comes last: two class runs at once on this machine (its Ray
# nodes' and check_fk_class's hostile class) left a control group's cpu folder behind in 3 of 5 loaded runs (not
# understood yet), so CLASS_RUNS never overlap.
LONGEST_FIRST = ['launch.test', 'pytest', 'check_fk.test', 'launch_rviz.test',
                 'check_fk_class.test', 'cartpole_q_learning.test', 'policy_files.test', 'cartpole_robot.test',
                 'cartpole_search.test', 'reach_pose.test', 'across_machines.test', 'forward_kinematics_vs_rsp.test',
                 'ros_env.test',
                 'reach_ros.test', 'forward_kinematics_node.test', 'bench_output.test', 'check_fk_example.test',
                 'forward_kinematics_hz.test', 'roslaunch-check', 'ray_cluster.test']
CLASS_RUNS = {'check_fk_class.test', 'ray_cluster.test'}
_class_run = threading.Lock()


def targets() -> list[tuple[str, str]]:
    """(name, make target) of every test, in LONGEST_FIRST's order."""
    found = {'pytest': '_run_tests_robot_ai_pytest_unit',
             'roslaunch-check': '_run_tests_robot_ai_roslaunch-check_launch'}
    for test in sorted((ROOT / 'test').glob('*.test')):
        found[test.name] = f'_run_tests_robot_ai_rostest_test_{test.name}'
    order = [n for n in LONGEST_FIRST if n in found] + sorted(n for n in found if n not in LONGEST_FIRST)
    return [(n, found[n]) for n in order]


def run(name: str, target: str, build: pathlib.Path, logs: pathlib.Path, t0: float) -> tuple[str, int, float]:
    if name in CLASS_RUNS:
        with _class_run:
            return _run(name, target, build, logs, t0)
    return _run(name, target, build, logs, t0)


def _run(name: str, target: str, build: pathlib.Path, logs: pathlib.Path, t0: float) -> tuple[str, int, float]:
    started = time.monotonic()
    with open(logs / f'{name}.log', 'wb') as log:
        # the target's own rule only: through the top-level Makefile every test target first cleans the results
        # folder (catkin's clean_test_results), which would delete the results of the tests beside it
        rule = f'robot_ai/CMakeFiles/{target}.dir'
        status = subprocess.call(['make', '--no-print-directory', '-f', f'{rule}/build.make', f'{rule}/build'],
                                 cwd=build, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    seconds = time.monotonic() - started
    print(f'[{time.monotonic() - t0:6.0f} s] {name:<34} ended after {seconds:5.0f} s'
          + ('' if status == 0 else f' (make status {status}; its log: {logs / (name + ".log")})'), flush=True)
    if status:
        tail = (logs / f'{name}.log').read_bytes().decode(errors='replace').splitlines()[-15:]
        print('\n'.join('    | ' + line for line in tail), flush=True)
    return name, status, seconds


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--build', required=True, help='the catkin workspace\'s build folder')
    p.add_argument('--jobs', type=int, default=4, help='tests at a time')
    p.add_argument('--only', nargs='*', default=None, help='names of tests to run (launch.test, pytest, ...)')
    a = p.parse_args(argv)
    build = pathlib.Path(a.build).resolve()
    logs = build / 'test_logs'
    logs.mkdir(parents=True, exist_ok=True)
    chosen = [(n, t) for n, t in targets() if a.only is None or n in a.only]
    t0 = time.monotonic()
    print(f'{len(chosen)} test targets, {a.jobs} at a time (load average {os.getloadavg()[0]:.1f})', flush=True)
    load = LoadSampler()
    with concurrent.futures.ThreadPoolExecutor(a.jobs) as pool:
        done = list(pool.map(lambda nt: run(*nt, build, logs, t0), chosen))
    wall = time.monotonic() - t0
    print(f'all tests ended in {wall:.0f} s; alone they took {sum(s for _, _, s in done):.0f} s', flush=True)
    load.stop(build / 'test_results' / 'robot_ai' / LOAD_FILE, wall)
    return 0


LOAD_FILE = 'load_average.txt'      # what the run's load was, for test/summarize.py's summary


class LoadSampler:
    """The machine's 1-minute load average every 5 s while the tests run (the tests' own load and anything else's):
    a failure on a machine at ten times its cores' load reads differently from one on a quiet machine."""

    def __init__(self, every: float = 5.0):
        self.samples, self.done = [os.getloadavg()[0]], threading.Event()
        self.thread = threading.Thread(target=self._sample, args=(every,), daemon=True)
        self.thread.start()

    def _sample(self, every: float) -> None:
        while not self.done.wait(every):
            self.samples.append(os.getloadavg()[0])

    def stop(self, path: pathlib.Path, wall: float) -> None:
        self.done.set()
        self.thread.join()
        line = (f'load average over the run: {sum(self.samples) / len(self.samples):.1f} mean, '
                f'{max(self.samples):.1f} at most, on {os.cpu_count()} cores; the tests took {wall:.0f} s')
        print(line, flush=True)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(line + '\n')


if __name__ == '__main__':
    sys.exit(main())
