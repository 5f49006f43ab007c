"""robot_ai.fleet and the Ray side of a class run (robot_ai.grading.on_ray) without a cluster: one line for Ray
missing or a cluster that is not there, and a node that cannot sandbox grades nobody. The cluster itself:
test/test_ray_cluster.py (a rostest). No rospy."""
from __future__ import annotations

import socket
import subprocess
import sys

import pytest

from robot_ai import fleet
from robot_ai.grading import on_ray, sandbox
from robot_ai.grading.class_run import Judging


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
