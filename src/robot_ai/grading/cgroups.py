"""A share of the machine per student: a control group of the kernel's for each student's judge and everything it
starts (the student's node, its roscore, whatever the node forks), written directly in the cgroup file system. No
rospy.

    group = Group.create('check_fk_1234_7', cores=1.0, memory_bytes=3 * 2 ** 30, processes=512)
    command = group.exec_prefix() + command          # the process joins the group before it runs anything
    clock = BudgetClock(budget, group.pressure_file)  # in the judge: its budget counts the time it was given a CPU
    group.kill(); group.remove()

On a cgroup v1 (hybrid) host such as Debian's in a container: the cpu controller (cpu.shares, an equal share of the
cores, and cpu.cfs_quota_us, at most `cores`), memory (memory.limit_in_bytes, the student and its judge together) and
pids (pids.max); the unified hierarchy, which has no controllers there, still keeps each group's CPU pressure and can
kill a group whole. On a cgroup v2 host, the same in one folder (cpu.weight, cpu.max, memory.max, pids.max).

Why: limits per process leave the machine to whoever starts most processes. A student that starts 200 busy loops, each
in a session of its own, is 200 scheduling groups to the kernel's autogroup, and a correct classmate graded beside it
missed its budget. In a group of its own each student gets the same share, and its budget (BudgetClock) counts the
time it was given: wall time less the time its group was stalled, every task of it waiting for a CPU.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

from robot_ai.child_process import alive

ROOT = '/sys/fs/cgroup'
PARENT = 'robot_ai_grading'
V1_CONTROLLERS = ('cpu', 'cpuacct', 'memory', 'pids')
PERIOD_US = 100_000
JOIN = ("import os, sys; i = sys.argv.index('--'); "
        "[open(p, 'w').write(str(os.getpid())) for p in sys.argv[1:i]]; os.execvp(sys.argv[i + 1], sys.argv[i + 1:])")


def _write(path: str, value) -> None:
    with open(path, 'w') as f:
        f.write(str(value))


def version() -> int:
    """2 on a unified host (controllers in /sys/fs/cgroup itself), 1 on a v1 or hybrid one, 0 without cgroups (or
    without the right to make groups: not root)."""
    if os.geteuid() != 0:
        return 0
    if os.path.exists(os.path.join(ROOT, 'cgroup.controllers')):
        return 2
    if all(os.path.isdir(os.path.join(ROOT, c)) for c in V1_CONTROLLERS):
        return 1
    return 0


@dataclass
class Group:
    """One student's control group: its folders (one per hierarchy), and where its CPU pressure is read."""
    name: str
    folders: list[str] = field(default_factory=list)
    pressure_file: str = ''
    kill_file: str = ''

    @classmethod
    def create(cls, name: str, cores: float, memory_bytes: int, processes: int) -> Group | None:
        """A new group with an equal CPU share capped at `cores`, `memory_bytes` for all its processes together and at
        most `processes` tasks; None where groups cannot be made here (then the sandbox's per-process limits stand
        alone)."""
        kind = version()
        if kind == 0:
            return None
        group = cls(name)
        try:
            if kind == 2:
                parent = os.path.join(ROOT, PARENT)
                os.makedirs(parent, exist_ok=True)
                _write(os.path.join(ROOT, 'cgroup.subtree_control'), '+cpu +memory +pids')
                _write(os.path.join(parent, 'cgroup.subtree_control'), '+cpu +memory +pids')
                folder = os.path.join(parent, name)
                os.mkdir(folder)
                group.folders.append(folder)
                _write(os.path.join(folder, 'cpu.weight'), 100)
                _write(os.path.join(folder, 'cpu.max'), f'{int(cores * PERIOD_US)} {PERIOD_US}')
                _write(os.path.join(folder, 'memory.max'), memory_bytes)
                _write(os.path.join(folder, 'pids.max'), processes)
                group.pressure_file = os.path.join(folder, 'cpu.pressure')
                group.kill_file = os.path.join(folder, 'cgroup.kill')
                return group
            for controller in V1_CONTROLLERS:
                folder = os.path.join(ROOT, controller, PARENT, name)
                os.makedirs(folder)
                group.folders.append(folder)
            cpu, _, memory, pids = group.folders
            _write(os.path.join(cpu, 'cpu.shares'), 1024)
            _write(os.path.join(cpu, 'cpu.cfs_period_us'), PERIOD_US)
            _write(os.path.join(cpu, 'cpu.cfs_quota_us'), int(cores * PERIOD_US))
            _write(os.path.join(memory, 'memory.limit_in_bytes'), memory_bytes)
            _write(os.path.join(pids, 'pids.max'), processes)
            unified = os.path.join(ROOT, 'unified')
            if os.path.exists(os.path.join(unified, 'cgroup.procs')):    # the hybrid host's v2 tree: pressure, kill
                folder = os.path.join(unified, PARENT, name)
                os.makedirs(folder)
                group.folders.append(folder)
                group.pressure_file = os.path.join(folder, 'cpu.pressure')
                group.kill_file = os.path.join(folder, 'cgroup.kill')
            return group
        except OSError:
            group.remove()
            return None

    def exec_prefix(self, python: str) -> list[str]:
        """The words before a command that make its process join this group before it runs anything (so that what it
        starts is in the group from its first instruction)."""
        return [python, '-c', JOIN] + [os.path.join(f, 'cgroup.procs') for f in self.folders] + ['--']

    def cpu_seconds(self) -> float:
        """CPU time its processes have used."""
        for folder in self.folders:
            try:
                if os.path.basename(os.path.dirname(os.path.dirname(folder))) == 'cpuacct':
                    with open(os.path.join(folder, 'cpuacct.usage')) as f:
                        return int(f.read()) / 1e9
                with open(os.path.join(folder, 'cpu.stat')) as f:
                    for line in f:
                        if line.startswith('usage_usec'):
                            return int(line.split()[1]) / 1e6
            except (OSError, ValueError):
                continue
        return 0.0

    def kill(self) -> None:
        """SIGKILL every process of the group (where the kernel can: cgroup.kill), else those its cgroup.procs name.
        The CPU cap is lifted first: a killed process still needs the CPU to exit, and sixty busy loops held to one
        core's quota took longer than the group's removal waited (its folder was left behind under load)."""
        for folder in self.folders:
            for name, unlimited in (('cpu.cfs_quota_us', -1), ('cpu.max', 'max')):
                path = os.path.join(folder, name)
                if os.path.exists(path):
                    try:
                        _write(path, unlimited)
                    except OSError:
                        pass
        if self.kill_file and os.path.exists(self.kill_file):
            try:
                _write(self.kill_file, 1)
                return
            except OSError:
                pass
        for folder in self.folders:
            try:
                with open(os.path.join(folder, 'cgroup.procs')) as f:
                    pids = [int(p) for p in f.read().split()]
            except (OSError, ValueError):
                continue
            for pid in pids:
                try:
                    os.kill(pid, 9)
                except ProcessLookupError:
                    pass

    def remove(self, wait: float = 20.0) -> None:
        """Remove the group's folders once its processes are gone (killed: kill()); on a loaded machine sixty killed
        busy loops take seconds to go, and a folder left behind would stay until the next class run's sweep."""
        deadline = time.monotonic() + wait
        for folder in reversed(self.folders):
            while os.path.isdir(folder):
                try:
                    os.rmdir(folder)
                except OSError:
                    if time.monotonic() > deadline:
                        break
                    time.sleep(0.05)


def stalled_seconds(pressure_file: str) -> float:
    """The time every task of the group was waiting for a CPU (PSI's 'full' total), 0.0 where it cannot be read."""
    try:
        with open(pressure_file) as f:
            for line in f:
                if line.startswith('full'):
                    return int(line.rsplit('total=', 1)[1]) / 1e6
    except (OSError, ValueError, IndexError):
        pass
    return 0.0


class BudgetClock:
    """A budget counted in the time a student was given: wall seconds less the seconds its whole group waited for a
    CPU that others held (a loaded machine, a classmate's processes). Without a pressure file: wall seconds."""

    def __init__(self, budget: float, pressure_file: str = ''):
        self.budget = budget
        self.pressure_file = pressure_file if pressure_file and os.path.exists(pressure_file) else ''
        self.started = time.monotonic()
        self.stalled_at_start = stalled_seconds(self.pressure_file) if self.pressure_file else 0.0

    def used(self) -> float:
        wall = time.monotonic() - self.started
        if not self.pressure_file:
            return wall
        return max(0.0, wall - (stalled_seconds(self.pressure_file) - self.stalled_at_start))

    def over(self) -> bool:
        return self.used() > self.budget


def sweep(prefix: str = 'check_fk_', maker: int | None = None) -> list[str]:
    """Kill and remove the groups named `<prefix><pid>_<n>` whose maker (process pid) has ended without removing them:
    a class run's grader, or a Ray worker, killed with SIGKILL (a Ray node's worker dies with its task's cancel or its
    raylet); with maker, that process's own groups (a class run's last look: none of its groups outlives it, whatever
    a folder's removal met under load). Their names."""
    if version() == 0:
        return []
    parents = [os.path.join(ROOT, PARENT)] + [os.path.join(ROOT, c, PARENT) for c in V1_CONTROLLERS + ('unified',)]
    stale = {}
    for parent in parents:
        try:
            names = os.listdir(parent)
        except OSError:
            continue
        for name in names:
            pid = name[len(prefix):].split('_')[0] if name.startswith(prefix) else ''
            if not pid.isdigit() or not os.path.isdir(os.path.join(parent, name)):
                continue
            if (int(pid) == maker) if maker is not None else not alive(int(pid)):
                stale.setdefault(name, []).append(os.path.join(parent, name))
    for name, folders in stale.items():
        group = Group(name, folders=folders)
        unified = [f for f in folders if os.path.exists(os.path.join(f, 'cgroup.kill'))]
        group.kill_file = os.path.join(unified[0], 'cgroup.kill') if unified else ''
        group.kill()
        group.remove()
    return sorted(stale)
