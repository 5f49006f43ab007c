"""Run a command (roslaunch) so that nothing it started outlives it. No rospy.

    python -m robot_ai.launch_guard roslaunch -p 11411 robot_ai demo.launch 2>&1 | tee demo.log

roslaunch starts every node in a session of its own and ends them itself; killed with SIGKILL it cannot, and its
nodes (the master, rosout, rviz, ...) run on, holding its output pipe, so that `make demo`'s `tee` waited forever.
The guard makes itself the subreaper of the command's descendants (Linux's PR_SET_CHILD_SUBREAPER): when the
command ends, however it ends, what it left behind is reparented to the guard, which sends it SIGINT (what
roslaunch sends), then SIGTERM after GRACE_SECONDS, then SIGKILL, and exits with the command's status.

A Ctrl-C reaches the command from the terminal and the guard waits for it; a SIGTERM or SIGHUP to the guard is
passed on to the command.
"""
import os
import signal
import subprocess
import sys
import time

from robot_ai.child_process import PR_SET_CHILD_SUBREAPER, descendants, prctl, reap

GRACE_SECONDS = 5.0


def end_leftovers(grace: float = GRACE_SECONDS) -> list[int]:
    """SIGINT, then SIGTERM, then SIGKILL to every process left below the guard; the pids that were left."""
    left = descendants(os.getpid())
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        for pid in descendants(os.getpid()):
            try:
                os.kill(pid, signum)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + grace
        while time.monotonic() < deadline:
            reap()
            if not descendants(os.getpid()):
                return left
            time.sleep(0.05)
    return left


def main(argv: list[str] | None = None) -> int:
    command = sys.argv[1:] if argv is None else argv
    if not command:
        print('usage: python -m robot_ai.launch_guard COMMAND [ARG ...]', file=sys.stderr)
        return 2
    if not prctl(PR_SET_CHILD_SUBREAPER, 1):
        print('launch_guard: this system cannot adopt orphans (PR_SET_CHILD_SUBREAPER); running the command '
              'unguarded', file=sys.stderr)
    child: dict = {'pid': None, 'pending': []}

    def pass_on(signum, frame):
        if child['pid'] is None:
            child['pending'].append(signum)  # before the command has started: sent once it has
        else:
            os.kill(child['pid'], signum)    # not reaped before the loop below reaps it: the pid is still the command's
    signal.signal(signal.SIGINT, lambda signum, frame: None)  # the terminal sends it to the command too
    signal.signal(signal.SIGTERM, pass_on)
    signal.signal(signal.SIGHUP, pass_on)
    proc = subprocess.Popen(command)
    child['pid'] = proc.pid
    for signum in child['pending']:
        os.kill(proc.pid, signum)
    while True:  # reap the orphans the command's processes leave as they go, until the command itself ends
        pid, wait_status = os.waitpid(-1, 0)
        if pid == proc.pid:
            status = os.waitstatus_to_exitcode(wait_status)
            break
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)
    left = end_leftovers()
    if left:
        print(f'launch_guard: {command[0]} ended ({describe(status)}) and left {len(left)} processes running; '
              'ended them', file=sys.stderr)
    return status if status >= 0 else 128 - status


def describe(status: int) -> str:
    return f'killed by {signal.Signals(-status).name}' if status < 0 else f'status {status}'


if __name__ == '__main__':
    sys.exit(main())
