"""robot_ai.grading.master: a check's own master keeps at most PARAM_BYTES of parameters and reads no request much
larger, says who it refused, and is otherwise ROS's master (issue 56: a student stored 1,200 MiB through its
judge's)."""
import os
import signal
import socket
import subprocess
import sys
import time
import xmlrpc.client

import pytest

from robot_ai.grading.master import PARAM_BYTES, ParamBudget, read_refused, size_of


def test_the_bytes_of_a_value_are_its_strings_and_items():
    assert size_of('x' * 1000) == 1016
    assert size_of({'a': 'x' * 100, 'b': [1, 2.0, True]}) > 100
    assert size_of(xmlrpc.client.Binary(b'\0' * 500)) == 516


def test_a_budget_counts_what_is_held_now_and_refuses_past_its_limit(tmp_path):
    refused = str(tmp_path / 'refused.json')
    budget = ParamBudget(10_000, refused)
    for _ in range(50):                                # the same key set again and again holds one value
        budget.set('/a', 'x' * 4000, '/node')
    budget.set('/ns/b', 'x' * 4000, '/node')
    with pytest.raises(ValueError, match='refused'):
        budget.set('/c', 'x' * 4000, '/student')
    assert read_refused(refused)['caller'] == '/student'
    budget.set('/ns', {'only': 1}, '/node')            # a namespace set anew replaces what was under it
    budget.set('/c', 'x' * 4000, '/node')
    budget.delete('/a')
    assert budget.total < 10_000 - 3000


def free_port():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def test_a_live_master_refuses_the_parameter_past_the_bound_and_serves_on(tmp_path):
    port, refused = free_port(), str(tmp_path / 'refused.json')
    proc = subprocess.Popen([sys.executable, '-m', 'robot_ai.grading.master', str(port), refused],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    master = xmlrpc.client.ServerProxy(f'http://127.0.0.1:{port}')
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                if master.getParam('/test', '/run_id')[0] == 1:   # set as roscore sets it, and /rosdistro
                    break
            except OSError:
                pass
            assert time.monotonic() < deadline and proc.poll() is None, proc.stderr.read().decode()[-2000:]
            time.sleep(0.2)
        chunk = 'x' * (8 * 1024 ** 2)
        codes = [master.setParam('/student', f'/junk/{i}', chunk)[0] for i in range(PARAM_BYTES // len(chunk) + 2)]
        assert codes[:7] == [1] * 7 and codes[-1] != 1, codes          # ROS's error code to the caller
        assert read_refused(refused)['caller'] == '/student'
        with pytest.raises((xmlrpc.client.ProtocolError, OSError)):   # one request past the bound is not read
            master.setParam('/student', '/huge', 'y' * (PARAM_BYTES + 2 * 1024 ** 2))
        master = xmlrpc.client.ServerProxy(f'http://127.0.0.1:{port}')
        assert master.setParam('/other', '/small', 'ok')[0] == 1 and master.getParam('/x', '/small')[2] == 'ok'
        assert master.deleteParam('/student', '/junk')[0] == 1        # what was freed can be set again
        assert master.setParam('/student', '/again', chunk)[0] == 1
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
