"""robot_ai.grading.sandbox: escaping, the copy of a candidate's folder, and what a sandboxed process sees (as root,
with bubblewrap and util-linux, as make test runs). No rospy."""
from __future__ import annotations

import os
import stat
import subprocess
import sys
import tempfile

import pytest

from robot_ai.grading import sandbox


def test_printable_keeps_every_verdict_on_one_line():
    assert sandbox.printable('a\nPASS') == 'a\\nPASS'
    assert sandbox.printable('bye\rPASS') == 'bye\\rPASS'
    assert sandbox.printable('\x1b[2K\u202eSSAP') == '\\x1b[2K\\u202eSSAP'
    assert sandbox.printable('a\\nb') == 'a\\\\nb'                  # a written backslash cannot forge an escape
    assert sandbox.printable('a\\nb', backslashes=False) == 'a\\nb'
    assert sandbox.printable('x' * 50, 10) == 'x' * 10 + '...'


def test_copy_folder_copies_files_and_links_read_only_for_the_uid(tmp_path):
    source = tmp_path / 'student'
    (source / 'pkg').mkdir(parents=True)
    (source / 'fk.py').write_text('print(1)\n')
    (source / 'run.sh').write_text('#!/bin/sh\n')
    (source / 'run.sh').chmod(0o700)
    (source / 'link.py').symlink_to('fk.py')
    os.mkfifo(source / 'pipe')
    target = tmp_path / 'copy'
    sandbox.copy_folder(str(source), str(target), os.getuid())
    assert sorted(os.listdir(target)) == ['fk.py', 'link.py', 'pkg', 'run.sh']     # no FIFO
    assert os.path.islink(target / 'link.py')
    assert stat.S_IMODE(os.stat(target / 'fk.py').st_mode) == 0o444
    assert stat.S_IMODE(os.stat(target / 'run.sh').st_mode) == 0o555
    assert stat.S_IMODE(os.stat(target).st_mode) == 0o555
    with pytest.raises(sandbox.SandboxError):
        sandbox.copy_folder(str(source), str(tmp_path / 'small'), os.getuid(), max_files=2)


def test_a_packed_folder_unpacks_as_copy_folder_copies_it(tmp_path):
    """What a class run ships to a Ray node: files (their bytes, the executable bit), folders, links as links (one
    to outside the folder too, never followed), no FIFO; the copy limits hold before anything is read."""
    source = tmp_path / 'student'
    (source / 'pkg' / 'deep').mkdir(parents=True)
    (source / 'fk.py').write_bytes(b'print(1)\n\x00\xff')
    (source / 'pkg' / 'deep' / 'node.py').write_text('import rospy\n')
    (source / 'run.sh').write_text('#!/bin/sh\n')
    (source / 'run.sh').chmod(0o700)
    (source / 'link.py').symlink_to('fk.py')
    (source / 'out').symlink_to('/etc')
    os.mkfifo(source / 'pipe')
    packed = sandbox.pack_folder(str(source))
    target = tmp_path / 'unpacked'
    sandbox.unpack_folder(packed, str(target))
    assert sorted(os.listdir(target)) == ['fk.py', 'link.py', 'out', 'pkg', 'run.sh']
    assert (target / 'fk.py').read_bytes() == b'print(1)\n\x00\xff'
    assert (target / 'pkg' / 'deep' / 'node.py').read_text() == 'import rospy\n'
    assert os.readlink(target / 'link.py') == 'fk.py' and os.readlink(target / 'out') == '/etc'
    assert os.access(target / 'run.sh', os.X_OK) and not os.access(target / 'fk.py', os.X_OK)
    assert packed.size == len(b'print(1)\n\x00\xff') + len('import rospy\n') + len('#!/bin/sh\n') + 5 + 4
    with pytest.raises(sandbox.SandboxError, match='more than 2 files'):
        sandbox.pack_folder(str(source), max_files=2)
    with pytest.raises(sandbox.SandboxError, match='more than'):
        sandbox.pack_folder(str(source), max_bytes=10)


@pytest.mark.parametrize('entry', [
    ('../escaped', 'file', 0o644, b'x'), ('/tmp/escaped', 'file', 0o644, b'x'),
    ('a/../../escaped', 'file', 0o644, b'x'),
    ('out/escaped', 'file', 0o644, b'x'), ('nodir/escaped', 'file', 0o644, b'x'), ('', 'dir', 0o755, b''),
    ('x', 'device', 0, b''), ('x', 'file', 0o644, 'not bytes'), ('x',)])
def test_an_unpacked_folder_never_writes_outside_its_target(tmp_path, entry):
    """The data came over the network: a path that climbs out, is absolute, or lies below a link or a folder the
    data did not make is refused, and nothing is written outside the target."""
    packed = sandbox.Packed((('out', 'link', 0, str(tmp_path)), entry))
    with pytest.raises(sandbox.SandboxError):
        sandbox.unpack_folder(packed, str(tmp_path / 'target'))
    assert sorted(os.listdir(tmp_path)) == ['target']


def test_a_sandboxed_process_sees_the_paths_it_needs_under_tmp_and_nothing_of_the_graders():
    """A checkout under /tmp (its venv and workspace on PYTHONPATH) stays visible above the sandbox's own /tmp; the
    grader's files do not; the process runs as its uid and cannot write what it sees."""
    problem = sandbox.unavailable()
    if problem:
        pytest.skip(problem)       # make test runs as root, where this never skips (a skip fails its summary)
    with tempfile.TemporaryDirectory(dir='/tmp') as outside:
        library = os.path.join(outside, 'checkout', 'lib')
        os.makedirs(library)
        with open(os.path.join(library, 'probe_module.py'), 'w') as f:
            f.write('VALUE = 42\n')
        secret = os.path.join(outside, 'grader_secret.txt')
        with open(secret, 'w') as f:
            f.write('the answers\n')
        work = os.path.join(outside, 'work')
        os.mkdir(work)
        copy = os.path.join(work, 'student')
        os.mkdir(os.path.join(outside, 'student'))
        sandbox.copy_folder(os.path.join(outside, 'student'), copy, sandbox.uid_for(os.getpid(), 1))
        env = dict(os.environ, PYTHONPATH=library)
        uid = sandbox.uid_for(os.getpid(), 1)
        script = (f'import os, probe_module; print(probe_module.VALUE, os.getuid(), os.path.exists({secret!r}), '
                  f'os.access({library!r}, os.W_OK), os.getcwd())')
        argv, kept = sandbox.candidate_command([sys.executable, '-c', script], uid, copy, sandbox.Limits(), env=env)
        out = subprocess.run(argv, env=kept, capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        assert out.stdout.split() == ['42', str(uid), 'False', 'False', '/student']
