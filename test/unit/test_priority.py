"""robot_ai.priority: every thread of a process, and those started afterwards, at the nice value asked for where the
machine allows it; nothing changed, and said, where it does not; a lower value is never raised."""
import json
import os
import shutil
import subprocess
import sys
import tempfile

import pytest

SRC = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', '..', 'src')
SYSTEM_PYTHON = getattr(sys, '_base_executable', '') or '/usr/bin/python3'   # outside the venv: a folder the user
                                                                              # may not read
PROBE = f"""
import json, os, sys, threading
sys.path.insert(0, {os.path.realpath(SRC)!r})
from robot_ai.priority import raise_priority
started = threading.Event()
waiting = threading.Thread(target=started.wait, daemon=True)        # a thread that exists before
waiting.start()
note = raise_priority(int(sys.argv[1]))
after = {{}}
later = threading.Thread(target=lambda: after.update(nice=os.getpriority(os.PRIO_PROCESS, 0)))
later.start()
later.join()
threads = []
for t in os.listdir('/proc/self/task'):
    try:
        threads.append(os.getpriority(os.PRIO_PROCESS, int(t)))
    except ProcessLookupError:                            # `later`, gone since the listing
        pass
started.set()
print(json.dumps(dict(note=note, threads=threads, later=after['nice'])))
"""


def probe(nice: int, *prefix: str) -> dict:
    if not prefix:
        out = subprocess.run([sys.executable, '-c', PROBE, str(nice)], capture_output=True, text=True, timeout=60,
                             cwd='/')
        assert out.returncode == 0, out.stderr
        return json.loads(out.stdout)
    # another user runs the probe: the checkout (and the venv in it) may be a folder only its owner reads (a
    # `mktemp -d` clone), so the module goes to a world-readable folder of its own and the system's Python runs it
    with tempfile.TemporaryDirectory() as folder:
        os.chmod(folder, 0o755)
        package = os.path.join(folder, 'robot_ai')
        os.mkdir(package)
        open(os.path.join(package, '__init__.py'), 'w').close()
        shutil.copy(os.path.join(SRC, 'robot_ai', 'priority.py'), package)
        for root, dirs, files in os.walk(folder):
            for name in dirs + files:
                os.chmod(os.path.join(root, name), 0o755 if name in dirs else 0o644)
        probe_text = PROBE.replace(repr(os.path.realpath(SRC)), repr(folder))
        out = subprocess.run([*prefix, SYSTEM_PYTHON, '-c', probe_text, str(nice)], capture_output=True, text=True,
                             timeout=60, cwd='/')
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def unprivileged() -> list[str]:
    """A prefix that runs a command without the right to raise a priority (as nobody, no capabilities)."""
    if os.geteuid() != 0:
        return []
    return [shutil.which('setpriv') or '/usr/bin/setpriv', '--reuid=65534', '--regid=65534', '--clear-groups',
            '--inh-caps=-all']


def test_every_thread_and_those_started_after_run_at_the_nice_value_asked():
    found = probe(-3)
    if os.geteuid() != 0:             # no right to it here: nothing changes, and the note says why
        assert found['threads'] == [0] * len(found['threads']) and 'needs root' in found['note']
        return
    assert len(found['threads']) >= 2
    assert found['threads'] == [-3] * len(found['threads']), found
    assert found['later'] == -3
    assert 'nice -3' in found['note']


def test_without_the_right_nothing_changes_and_the_note_says_why():
    found = probe(-3, *unprivileged())
    assert found['threads'] == [0] * len(found['threads']) and found['later'] == 0
    assert 'needs root or CAP_SYS_NICE' in found['note']


def test_a_process_started_at_a_higher_priority_keeps_it():
    if os.geteuid() != 0:             # only root starts a process below nice 0: a higher nice must be kept too
        found = probe(-3, 'nice', '-n', '5')
        assert found['threads'] == [5] * len(found['threads'])
        return
    found = probe(-3, 'nice', '-n', '-7')
    assert found['threads'] == [-7] * len(found['threads']) and found['later'] == -7
    assert 'own priority' in found['note']


def test_a_nice_value_out_of_range_is_refused():
    from robot_ai.priority import raise_priority
    with pytest.raises(ValueError, match='-20 to 19'):
        raise_priority(-21)
