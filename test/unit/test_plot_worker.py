"""robot_ai.plot_worker: one JSON line a plot; bad lines reported; quiet at end of input and on signals."""
import signal
import subprocess
import sys
import time

from robot_ai.cartpole import outputs
from robot_ai.cartpole.dynamics import CartPoleDynamics
from robot_ai.cartpole.linear_search import random_search
from robot_ai.plot_worker import job_line


def start():
    return subprocess.Popen([sys.executable, '-m', 'robot_ai.plot_worker'], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_draws_jobs_and_survives_bad_ones(tmp_path):
    res = random_search(CartPoleDynamics.of('CartPole-v1'), 10, 5, seed=2, final_episodes=5)
    good = str(tmp_path / 'curve.png')
    proc = subprocess.run([sys.executable, '-m', 'robot_ai.plot_worker'],
                          input='{"not": "a job"}\n' + job_line(outputs.search_plot_job(res), good),
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0
    assert 'failed' in proc.stderr and 'Traceback' not in proc.stderr
    assert proc.stdout.strip() == 'written %s' % good
    with open(good, 'rb') as f:
        assert f.read(8) == b'\x89PNG\r\n\x1a\n'


def test_ends_quietly_on_signals():
    for sig in (signal.SIGINT, signal.SIGTERM):
        proc = start()
        time.sleep(1.5)  # inside the loop, waiting for input
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
        assert proc.returncode == 0 and err == '', (sig, err)
    proc = start()
    proc.send_signal(signal.SIGINT)  # at once: while it still imports
    out, err = proc.communicate(timeout=30)
    assert 'Traceback' not in err, err
