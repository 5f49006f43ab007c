#!/usr/bin/env python3
"""A class graded on this machine and on a Ray cluster of two nodes on this same machine (the same cores: the
difference is Ray's overhead, not a speed-up), and what a MOOC's class costs on a fleet, on paper.

- students per minute: check_fk --candidates with --jobs 2 (the local run), then with --ray on a two-node cluster
  (ray.cluster_utils.Cluster: a head that runs nothing, two raylets of one CPU each), the same class of right and
  wrong course-style nodes on the KUKA LWR (the check_fk defaults: 50 configurations);
- Ray's own costs: the cluster's start, a driver's connection, and the round trip of an empty task (p50 over 200);
- on paper: 5,000 submissions on 20 machines of 2 cores, from the per-student time measured here.

    python bench/class_on_ray.py [--students 8] [--configurations 50]
"""
import argparse
import csv
import os
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.realpath(__file__))
ROOT = os.path.join(HERE, '..')
sys.path.insert(0, os.path.join(ROOT, 'src'))
ROBOTS = os.path.join(ROOT, '..', 'shared', 'robots')

from robot_ai import fleet  # noqa: E402


def write_class(folder: str, students: int) -> str:
    with open(os.path.join(ROOT, 'test', 'course_fk.py')) as f:
        course = f.read()
    klass = os.path.join(folder, 'class')
    for i in range(students):
        mistake = 'none' if i % 2 == 0 else 'first'
        os.makedirs(os.path.join(klass, f'student{i:03d}'))
        with open(os.path.join(klass, f'student{i:03d}', 'solution.py'), 'w') as f:
            f.write(course.replace("os.environ.get('COURSE_FK_MISTAKE', 'none')", repr(mistake)))
    return klass


def grade(klass: str, csv_path: str, configurations: int, *extra: str) -> tuple[float, list[dict]]:
    t = time.monotonic()
    proc = subprocess.run(['rosrun', 'robot_ai', 'check_fk', '--model', os.path.join(ROBOTS, 'kuka_lwr_arm.urdf'),
                           '--candidates', klass, '--configurations', str(configurations), '--csv', csv_path]
                          + list(extra), capture_output=True, text=True, timeout=3600)
    seconds = time.monotonic() - t
    if proc.returncode != 0:
        sys.exit(f'check_fk failed ({proc.returncode}): {proc.stdout[-2000:]}{proc.stderr[-2000:]}')
    with open(csv_path, newline='') as f:
        return seconds, list(csv.DictReader(f))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--students', type=int, default=8)
    p.add_argument('--configurations', type=int, default=50)
    a = p.parse_args()
    problem = fleet.available()
    if problem:
        print(f'a class on Ray: skipped: {problem}')
        return 0
    os.environ['RAY_USAGE_STATS_ENABLED'] = '0'
    folder = tempfile.mkdtemp(prefix='bench_class_on_ray_')
    try:
        klass = write_class(folder, a.students)
        local_s, local = grade(klass, os.path.join(folder, 'local.csv'), a.configurations, '--jobs', '2')
        t = time.monotonic()
        from ray.cluster_utils import Cluster
        cluster = Cluster(initialize_head=True, head_node_args={'num_cpus': 0})
        for _ in range(2):
            cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        start_s = time.monotonic() - t
        try:
            t = time.monotonic()
            ray = fleet.connect(cluster.address)
            connect_s = time.monotonic() - t
            empty = ray.remote(lambda: None).options(num_cpus=1)
            ray.get([empty.remote() for _ in range(4)])            # the workers started
            trips = []
            for _ in range(200):
                t = time.monotonic()
                ray.get(empty.remote())
                trips.append(time.monotonic() - t)
            ray.shutdown()
            ray_s, on_ray = grade(klass, os.path.join(folder, 'ray.csv'), a.configurations, '--ray', cluster.address)
        finally:
            cluster.shutdown()
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    same = [(r['student'], r['verdict'], r['score']) for r in local] == \
        [(r['student'], r['verdict'], r['score']) for r in on_ray]
    per_student = float(np.mean([float(r['seconds']) for r in local]))
    n = a.students
    print(f'a class of {n} course-style FK nodes on the KUKA LWR ({a.configurations} configurations), load average '
          f'{os.getloadavg()[0]:.2f}')
    print(f'{"":38s} {"wall s":>8s} {"students/min":>13s}')
    print(f'{"local, --jobs 2":38s} {local_s:8.1f} {60 * n / local_s:13.1f}')
    print(f'{"Ray, 2 nodes x 1 CPU, this machine":38s} {ray_s:8.1f} {60 * n / ray_s:13.1f}')
    print(f'the two CSVs hold the same verdicts and scores: {"yes" if same else "NO"}')
    print(f'Ray: cluster start {start_s:.1f} s, a driver connects in {connect_s:.2f} s, an empty task\'s round trip '
          f'p50 {1000 * np.median(trips):.1f} ms (p99 {1000 * np.percentile(trips, 99):.1f} ms); per student '
          f'{(ray_s - local_s) / n:+.1f} s against the local run')
    fleet_minutes = 5000 * per_student / (20 * 2) / 60
    print(f'on paper: 5,000 submissions on 20 machines of 2 cores: {per_student:.1f} s a student here, one per core '
          f'-> {fleet_minutes:.0f} min of grading ({5000 * per_student / 2 / 3600:.1f} h on this machine alone)')
    return 0 if same else 1


if __name__ == '__main__':
    sys.exit(main())
