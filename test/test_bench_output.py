#!/usr/bin/env python3
"""make bench as it runs each script: stdout (the table) holds no ROS log line, and last_figures.py prints the
last recorded figures (docs/benchmarks.md). The search benchmark runs small (--skip-large --calls 1): its output
format is what is checked."""
import os
import re
import subprocess
import sys
import unittest

import rostest

ROOT = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..')
LOG_LINE = re.compile(r'^\s*\[(INFO|WARN|ERROR|DEBUG|FATAL)\]|^\x1b\[')


class TestBenchOutput(unittest.TestCase):

    def test_search_table_has_no_ros_log_lines(self):
        proc = subprocess.run([sys.executable, os.path.join(ROOT, 'bench', 'search_speed.py'), '--skip-large',
                               '--calls', '1'], capture_output=True, text=True, timeout=240)
        self.assertEqual(proc.returncode, 0, proc.stderr[-2000:])
        lines = proc.stdout.splitlines()
        self.assertTrue(any(l.startswith('~random_search service, round trip') for l in lines), proc.stdout)
        self.assertEqual([l for l in lines if LOG_LINE.search(l)], [])

    def test_last_figures_come_first(self):
        out = subprocess.run([sys.executable, os.path.join(ROOT, 'bench', 'last_figures.py')], capture_output=True,
                             text=True, timeout=60).stdout
        self.assertRegex(out.splitlines()[1], r'^last recorded \(docs/benchmarks.md\): Figures of \d{4}-\d\d-\d\d')
        self.assertIn('CPU ratio forward_kinematics / robot_state_publisher', out)
        self.assertIn('today (', out)


if __name__ == '__main__':
    rostest.rosrun('robot_ai', 'test_bench_output', TestBenchOutput)
