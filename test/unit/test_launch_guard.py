"""robot_ai.launch_guard: whatever ends the command, what it started ends too, and the guard exits with its
status (the launch test does the same with roslaunch and a SIGKILL)."""
import os
import signal
import subprocess
import sys
import time

from robot_ai.child_process import ProcessStat, process_stat

SRC = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..', 'src'))


def guard(*command):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([SRC] + sys.path))
    return subprocess.Popen([sys.executable, '-m', 'robot_ai.launch_guard', *command], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def pids_of(command: str) -> list[int]:
    """The processes running exactly this command (not the guard or bash, whose arguments contain it)."""
    found = []
    for entry in filter(str.isdigit, os.listdir('/proc')):
        try:
            with open(f'/proc/{entry}/cmdline', 'rb') as f:
                if f.read() == command.replace(' ', '\0').encode() + b'\0':
                    found.append(int(entry))
        except OSError:
            pass
    return found


def test_what_the_command_leaves_is_ended_and_its_status_kept():
    proc = guard('bash', '-c', 'sleep 301 & sleep 0.5; exit 7')
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 7
    assert 'launch_guard: bash ended (status 7) and left 1 processes running; ended them' in err
    assert pids_of('sleep 301') == []


def test_a_command_killed_by_a_signal_and_a_sigterm_passed_on():
    proc = guard('bash', '-c', 'sleep 302 & wait')
    deadline = time.time() + 10
    while not pids_of('sleep 302') and time.time() < deadline:
        time.sleep(0.05)
    assert pids_of('sleep 302')
    proc.send_signal(signal.SIGTERM)            # passed on to bash, which dies of it
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 128 + signal.SIGTERM
    assert 'bash ended (killed by SIGTERM)' in err
    assert pids_of('sleep 302') == []


def test_orphans_are_reaped_while_the_command_runs():
    """Processes that end while the command runs leave no zombie under the guard."""
    proc = guard('bash', '-c', '(sleep 0.2 &) ; (sleep 0.2 &) ; sleep 2')
    time.sleep(1.2)
    zombies = [e for e in filter(str.isdigit, os.listdir('/proc'))
               if process_stat(int(e)) == ProcessStat('Z', proc.pid)]
    proc.communicate(timeout=30)
    assert zombies == []
    assert proc.returncode == 0
