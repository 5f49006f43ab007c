"""robot_ai.fleet and the Ray side of a class run (robot_ai.grading.on_ray) without a cluster: one line for Ray
missing or a cluster that is not there, and a node that cannot sandbox grades nobody. The cluster itself:
test/test_ray_cluster.py (a rostest). No rospy."""
from __future__ import annotations

import csv
import os
import signal
import socket
import subprocess
import sys
import time

import pytest

from robot_ai import fleet
from robot_ai.grading import on_ray, sandbox
from robot_ai.grading.class_run import Judging

ROBOTS_DIR = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', '..', '..', 'shared', 'robots')


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def test_no_cluster_at_an_address_is_one_line_at_once():
    for address in (f'127.0.0.1:{free_port()}', 'ray://127.0.0.1:1', ' '):
        with pytest.raises(fleet.FleetError) as e:
            fleet.connect(address)
        assert '\n' not in str(e.value)
        assert 'ray start --head' in str(e.value) or 'HOST:PORT' in str(e.value)


def test_ray_missing_is_one_line(monkeypatch):
    monkeypatch.setattr(fleet.importlib.util, 'find_spec', lambda name: None)
    assert 'pip install' in fleet.available()
    with pytest.raises(fleet.FleetError, match='not installed'):
        fleet.connect('auto')


def test_a_node_that_cannot_sandbox_grades_nobody(tmp_path, monkeypatch):
    """A node without root or without bubblewrap: its student's line says so, never PASS, and no judge runs."""
    monkeypatch.setattr(sandbox, 'unavailable', lambda: 'the sandbox needs bwrap')
    (tmp_path / 'fk.py').write_text('import rospy\nrospy.init_node("fk")\n')
    judging = Judging(('--model', 'x.urdf'), True, 60.0, sandbox.Limits(), '0/3 links')
    result, report = on_ray.grade_on_node(judging, 0, 'alice', '/class/alice', sandbox.pack_folder(str(tmp_path)), 1.0)
    assert result.verdict.startswith('not graded: Ray node ')
    assert result.verdict.endswith('cannot grade in a sandbox: the sandbox needs bwrap')
    assert not result.verdict.startswith('PASS') and result.score == ''
    assert report.decode().strip() == result.verdict


@pytest.mark.parametrize('command', [
    [sys.executable, '-m', 'robot_ai.reach', 'train', '--ray', 'ADDRESS'],
    [sys.executable, '-m', 'robot_ai.cartpole', 'q-learning', '--ray', 'ADDRESS'],
    [sys.executable, '-m', 'robot_ai.cartpole', 'ars', '--ray', 'ADDRESS'],
])
def test_the_command_lines_say_in_one_line_that_no_cluster_is_there(command, tmp_path):
    address = f'127.0.0.1:{free_port()}'
    proc = subprocess.run([w.replace('ADDRESS', address) for w in command] + ['--output-dir', str(tmp_path)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert f'--ray: no Ray cluster at {address}' in proc.stderr
    assert 'Traceback' not in proc.stderr


def test_check_fk_takes_ray_with_a_class_only(tmp_path):
    from robot_ai.nodes.check_fk import parse_args
    with pytest.raises(SystemExit) as e:
        parse_args(['--model', 'x.urdf', '--candidate', 'pkg/node', '--ray', 'auto'])
    assert e.value.code == 2
    a = parse_args(['--model', 'x.urdf', '--candidates', str(tmp_path), '--ray', 'auto'])
    assert a.ray == 'auto'


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM])
def test_a_signal_while_connecting_writes_the_csv_and_ends_with_its_status(signum, tmp_path, monkeypatch, capsys):
    """Connecting to a loaded cluster takes seconds: a Ctrl-C (or a SIGTERM) then stops the class as one mid-class
    does, every student in the CSV 'not graded (check_fk was stopped)', the status the signal's, and the handlers the
    caller had are back."""
    from robot_ai.grading.report import read_model
    from robot_ai.nodes.check_fk import parse_args
    for student in ('alice', 'bob'):
        (tmp_path / 'class' / student).mkdir(parents=True)
        (tmp_path / 'class' / student / 'fk.py').write_text('import rospy\n')
    csv_path = tmp_path / 'out.csv'
    model = os.path.join(ROBOTS_DIR, 'kuka_lwr_arm.urdf')
    a = parse_args(['--model', model, '--candidates', str(tmp_path / 'class'), '--csv', str(csv_path), '--ray',
                    f'127.0.0.1:{free_port()}'])

    def connecting(address):          # the signal arrives while ray.init waits for the cluster
        os.kill(os.getpid(), signum)
        time.sleep(30)
        raise AssertionError('the signal did not stop the wait')
    monkeypatch.setattr(fleet, 'connect', connecting)
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    xml, tree = read_model(model)
    assert on_ray.grade_class_on_ray(a, tree, xml) == 128 + signum
    with open(csv_path, newline='') as f:
        rows = list(csv.DictReader(f))
    assert [(r['student'], r['verdict']) for r in rows] == [
        ('alice', 'not graded (check_fk was stopped)'), ('bob', 'not graded (check_fk was stopped)')]
    assert 'check_fk: stopped: 0 of 2 graded (0 PASS)' in capsys.readouterr().out
    assert {s: signal.getsignal(s) for s in before} == before


def test_a_task_sweeps_the_folders_of_workers_killed_before_their_clean_up(tmp_path, monkeypatch):
    """A Ray worker killed mid-task (its node removed, OOM) leaves its work folder, a student's copy in it: the next
    task on the machine removes those whose worker is gone, and no other."""
    monkeypatch.setattr(on_ray.tempfile, 'tempdir', str(tmp_path))
    dead = subprocess.Popen(['true'])
    dead.wait()
    gone = tmp_path / f'{on_ray.WORK_PREFIX}{dead.pid}_x1'
    alive = tmp_path / f'{on_ray.WORK_PREFIX}{os.getpid()}_x2'
    other = tmp_path / f'{on_ray.WORK_PREFIX}abc'              # not a task's name: left alone
    for folder in (gone, alive, other):
        (folder / 'submitted').mkdir(parents=True)
        (folder / 'submitted' / 'fk.py').write_text('# a student\n')
    assert on_ray.dead_workers_folders() == [str(gone)]
    on_ray._sweep()
    assert not gone.exists() and alive.exists() and other.exists()
