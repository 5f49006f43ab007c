"""robot_ai.grading.cgroups: a student's group takes its processes from their first instruction, its CPU time and
pressure are read, the budget clock counts the time a CPU was given, and kill and remove leave nothing (as root, on
this machine's cgroup v1 hybrid hierarchy, as make test runs)."""
import os
import subprocess
import sys
import time

from robot_ai.grading import cgroups


def test_a_group_holds_what_its_process_starts_and_leaves_nothing():
    assert cgroups.version() in (1, 2), 'make test runs as root on a machine with cgroups'
    group = cgroups.Group.create(f'unit_{os.getpid()}', cores=0.5, memory_bytes=512 * 1024 ** 2, processes=64)
    assert group is not None and group.pressure_file
    try:
        busy = 'import os, time\nfor _ in range(3):\n    os.fork()\nt = time.time()\nwhile time.time() < t + 30: pass\n'
        proc = subprocess.Popen(group.exec_prefix(sys.executable) + [sys.executable, '-c', busy],
                                start_new_session=True)
        deadline, members = time.monotonic() + 60, []       # the forks, however loaded the machine
        while len(members) < 8 and time.monotonic() < deadline:
            time.sleep(0.1)
            with open(os.path.join(group.folders[0], 'cgroup.procs')) as f:
                members = [int(p) for p in f.read().split()]
        assert proc.pid in members and len(members) == 8, members      # the process and the 7 it forked
        before, t = group.cpu_seconds(), time.monotonic()
        time.sleep(2.0)
        used, wall = group.cpu_seconds() - before, time.monotonic() - t
        # 8 busy processes hold at most half a core (the cfs quota), loaded machine or not; they do run
        assert 0.0 < used < 0.5 * wall + 0.3, (used, wall)
        clock = cgroups.BudgetClock(100.0, group.pressure_file)
        time.sleep(1.0)
        assert clock.used() < 0.9, clock.used()  # its processes were stalled by their own quota, then given less
        group.kill()
        proc.wait(10)
    finally:
        group.kill()
        group.remove()
    assert not any(os.path.exists(f) for f in group.folders)


def test_without_a_pressure_file_the_clock_is_the_wall_clock():
    clock = cgroups.BudgetClock(0.2)
    assert not clock.over()
    time.sleep(0.3)
    assert clock.over() and 0.3 <= clock.used() < 2.0
