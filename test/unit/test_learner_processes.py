"""q_learning's learner processes: never forked (no OpenBLAS fork deadlock), a dead or stopped worker loses only
its learner and is noticed within seconds, workers never outlive their parent, the CLI ends them on SIGTERM/SIGHUP.

Every test is bounded in time: a hang is a failure, never a stuck test run."""
import os
import queue
import select
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest

from robot_ai.cartpole import q_learning as ql
from robot_ai.child_process import FrameReader, process_stat, spawn

SRC = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..', 'src'))


def small(episodes, learners, components=50):
    return ql.resolve(env_id='CartPole-v0', episodes=episodes, components=components, learners=learners)


def workers_of(pid: int) -> list[int]:
    """The processes whose parent is pid (its learner processes in these tests)."""
    return [int(e) for e in filter(str.isdigit, os.listdir('/proc'))
            if (stat := process_stat(int(e))) is not None and stat.ppid == pid]


def executing(pid: int) -> bool:
    """pid runs its own program (python -m <a worker module>): past the fork and the exec, whose window between
    holds the parent's descriptors (a loaded CI run looked into a worker there and found the parent's socket)."""
    try:
        with open(f'/proc/{pid}/cmdline', 'rb') as f:
            return b'\0-m\0' in f.read()
    except OSError:
        return False


def alive(pid: int) -> bool:
    stat = process_stat(pid)
    return stat is not None and stat.state != 'Z'


def wait_for(predicate, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f'not within {timeout} s: {what}')


def python(code: str, text: bool = True, **kw) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([SRC] + sys.path))
    return subprocess.Popen([sys.executable, '-c', textwrap.dedent(code)], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=text, **kw)


def test_trainings_started_while_other_threads_run_blas_never_deadlock():
    """The OpenBLAS fork deadlock: workers forked while threads of the parent were in a matrix product froze the
    parent for good (1 run in 3 of 40 trainings hung). Workers are spawned, not forked: 10 back-to-back trainings
    beside 3 threads of float32 matrix products (an ~evaluate each) all end. A count, not a time: a loaded machine
    runs fewer trainings in a time, and a deadlock is a training that never ends (none for 120 s)."""
    proc = python('''
        import threading, time
        import numpy as np
        from robot_ai.cartpole import q_learning as ql
        stop = threading.Event()
        def blas():
            a = np.random.default_rng(0).random((300, 300), dtype=np.float32)
            while not stop.is_set():
                a.dot(a)
        for _ in range(3):
            threading.Thread(target=blas, daemon=True).start()
        training = ql.resolve(episodes=20, components=50, learners=4)
        n = 0
        while n < 10:
            result = ql.train(training, n, workers=2)
            assert result.finished == [0, 1, 2, 3], result.failed
            n += 1
            print(n, flush=True)
        stop.set()
        for t in threading.enumerate():   # none left inside OpenBLAS at exit: its exit handler would wait for them
            if t is not threading.main_thread():
                t.join()
        print('trainings', n, flush=True)
    ''')
    lines, came = [], queue.Queue()
    threading.Thread(target=lambda: [came.put(line) for line in proc.stdout] + [came.put('')], daemon=True).start()
    try:
        while True:
            try:
                line = came.get(timeout=120)
            except queue.Empty:
                pytest.fail(f'deadlocked after {len(lines)} trainings: none ended for 120 s')
            if not line:
                break
            lines.append(line)
        proc.wait(60)
    finally:
        proc.kill()
        err = proc.stderr.read()
    assert proc.returncode == 0, err[-2000:]
    assert lines[-1].split() == ['trainings', '10'], lines


def kill_one_worker(signum, after_episode=20):
    """A progress callback that sends signum to one of this process's learner processes once any learner has
    played after_episode episodes; .pid and .at say which and when."""
    def progress(j, episode, total, eps):
        if progress.pid is None and episode >= after_episode:
            progress.pid = wait_for(lambda: workers_of(os.getpid()), 5, 'learner processes')[0]
            progress.at = time.monotonic()
            os.kill(progress.pid, signum)
    progress.pid = progress.at = None
    return progress


def test_a_killed_worker_loses_only_its_learner_and_is_noticed_at_once():
    training = small(episodes=200, learners=4)
    progress = kill_one_worker(signal.SIGKILL)
    result = ql.train(training, 7, progress=progress, workers=2)
    ended = time.monotonic()
    assert progress.pid is not None and not alive(progress.pid)
    assert len(result.failed) == 1, result.failed
    (lost, why), = result.failed.items()
    assert 'killed by SIGKILL' in why
    assert not result.cancelled
    # every other learner finished, in the survivor, equal to its single run
    assert result.finished == [j for j in range(4) if j != lost]
    for i, j in enumerate(result.finished):
        single, agent = ql.train_one(training, 7 + j)
        assert result.last100_averages[i] == single[-100:].mean()
        assert result.agents[j].q_weights.tobytes() == agent.q_weights.tobytes()
    assert ended - progress.at < 60  # the survivor trains up to 3 learners after the kill; no 72 s wait
    seeds = [7 + j for j in result.finished]    # the summary names the finished learners' seeds only
    named = (f'seeds {seeds[0]} to {seeds[-1]}' if seeds == list(range(seeds[0], seeds[-1] + 1))
             else f'seeds {", ".join(map(str, seeds))}')
    assert f'3 learners ({named})' in ql.summary(result)


def test_a_stopped_worker_is_killed_within_seconds_and_its_learner_reported():
    training = small(episodes=60, learners=2)
    progress = kill_one_worker(signal.SIGSTOP, after_episode=5)
    t0 = time.monotonic()
    result = ql.train(training, 0, progress=progress, workers=2)
    assert progress.pid is not None and not alive(progress.pid)
    assert len(result.failed) == 1, result.failed
    assert 'sent nothing for' in (why := list(result.failed.values())[0]) and '(stopped)' in why, why
    assert len(result.finished) == 1
    assert time.monotonic() - t0 < ql.SILENCE_SECONDS + 20


def test_a_worker_is_heard_from_its_start_not_only_once_it_has_work():
    """A worker's imports (numpy, gymnasium) take seconds on a loaded machine: that is not silence. It sends its
    heartbeat from its start, before it is told anything."""
    worker = spawn('robot_ai.cartpole.learner_worker')
    try:
        reader, frames, deadline = FrameReader(), [], time.monotonic() + 30
        while len(frames) < 3 and time.monotonic() < deadline:
            if select.select([worker.stdout], [], [], 1)[0]:
                frames += reader.feed(os.read(worker.stdout.fileno(), 1 << 16))
        assert frames[:3] == [('alive',)] * 3, frames
    finally:
        worker.kill()
        worker.communicate()


def test_a_pause_of_the_whole_machine_is_nobodys_silence():
    """The parent and its workers all stopped for longer than SILENCE_SECONDS (a paused VM, a starved machine),
    then running again, the parent first: no worker is taken for silent, every learner finishes."""
    parent = python('''
        import sys
        from robot_ai.cartpole import q_learning as ql
        def progress(j, episode, total, eps):
            if episode == 1 and j == 0:
                print('started', flush=True)
        training = ql.resolve(env_id='CartPole-v0', episodes=1500, components=200, learners=2)
        result = ql.train(training, 0, progress=progress, workers=2)
        print(result.finished, result.failed, flush=True)
    ''')
    try:
        assert parent.stdout.readline() == 'started\n'
        workers = workers_of(parent.pid)
        assert len(workers) == 2
        for pid in workers + [parent.pid]:
            os.kill(pid, signal.SIGSTOP)
        time.sleep(ql.SILENCE_SECONDS + 2)
        os.kill(parent.pid, signal.SIGCONT)
        time.sleep(0.5)
        for pid in workers:
            try:
                os.kill(pid, signal.SIGCONT)
            except ProcessLookupError:   # taken for silent and killed: the parent's output says so
                pass
        out, err = parent.communicate(timeout=900)     # a loaded machine's pace: the test is the outcome
        assert out == '[0, 1] {}\n', err[-2000:]
    finally:
        parent.kill()
        parent.communicate()


@pytest.mark.parametrize('after', ['exit', 'sleep'])
def test_a_result_cut_short_never_blocks_the_parent(monkeypatch, after):
    """A worker killed while writing its result: the parent reads what came, never waits for the rest."""
    fake = f'''
        import os, struct, sys, time
        from robot_ai.child_process import write_frame
        out = sys.stdout.buffer
        write_frame(out, ('alive',))
        out.write(struct.pack('<Q', 100000) + b'x' * 10)   # a frame's header and the start of its pickle
        out.flush()
        {'time.sleep(120)' if after == 'sleep' else 'os._exit(9)'}
    '''
    monkeypatch.setattr(ql, 'spawn', lambda module: python(fake, stdin=subprocess.PIPE, text=False))
    t0 = time.monotonic()
    with pytest.raises(RuntimeError, match='every learner failed'):
        ql.train(small(episodes=5, learners=2), 0, workers=2)
    assert time.monotonic() - t0 < ql.SILENCE_SECONDS + 5


@pytest.mark.parametrize('signum', [signal.SIGKILL, signal.SIGTERM])
def test_workers_end_with_their_parent_however_it_ends(signum):
    parent = python('''
        import socket
        from robot_ai.cartpole import q_learning as ql
        server = socket.create_server(('127.0.0.1', 0))   # a node's port: no worker may hold it
        ql.train(ql.resolve(episodes=5000, components=200, learners=2), 0, workers=2)
    ''')
    try:
        workers = wait_for(lambda: len(ws := workers_of(parent.pid)) == 2 and all(map(executing, ws)) and ws, 30,
                           'two workers past their exec')
        for w in workers:   # nothing of the parent's but the pipes to it: no socket, no other child's pipe
            links = []
            for fd in os.listdir(f'/proc/{w}/fd'):
                try:
                    links.append(os.readlink(f'/proc/{w}/fd/{fd}'))
                except FileNotFoundError:   # closed between the listing and the look (a module being read)
                    pass
            assert not [link for link in links if link.startswith('socket:')], links
        os.kill(parent.pid, signum)
        parent.wait(10)
        wait_for(lambda: not any(alive(w) for w in workers), 5, f'workers gone after a {signum.name} of the parent')
    finally:
        parent.kill()
        parent.communicate()


@pytest.mark.parametrize('signum', [signal.SIGTERM, signal.SIGHUP])
def test_the_cli_ends_its_workers_on_sigterm_and_sighup(tmp_path, signum):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([SRC] + sys.path))
    cli = subprocess.Popen([sys.executable, '-m', 'robot_ai.cartpole', 'q-learning', '--learners', '2', '--episodes',
                            '5000', '--output-dir', str(tmp_path)], env=env, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    try:
        workers = wait_for(lambda: len(workers_of(cli.pid)) == 2 and workers_of(cli.pid), 30, 'two workers')
        time.sleep(0.5)
        cli.send_signal(signum)
        _, err = cli.communicate(timeout=10)
        assert cli.returncode == 128 + signum
        assert f'interrupted by {signum.name}' in err.splitlines()
        assert 'Traceback' not in err
        wait_for(lambda: not any(alive(w) for w in workers), 5, 'workers gone')
    finally:
        cli.kill()
