"""A class graded across machines on a Ray cluster (``check_fk --candidates DIR --ray ADDRESS``). No rospy.

Each student is a Ray task: its folder is read here within the sandbox's copy limits (robot_ai.grading.sandbox
.pack_folder) and shipped as data; on whichever node the task lands, the same judge as a local run's
(robot_ai.grading.class_run.Judges) grades it in a sandbox of that node and returns the verdict record and the
report. This side orders, prints and writes exactly what a local run does: the same lines, the same CSV, the same
report files. A task holds one CPU (or a node's CPUs divided by --jobs), and at most two tasks per CPU of the cluster
are in flight, so the class's folders are never all in memory at once.

- A node that dies mid-class: Ray runs its students' tasks again elsewhere (MAX_RETRIES); a verdict is printed and
  written here only, once, when its task returns.
- A node that cannot sandbox (no root, a missing tool): each of its students gets one line saying so, not graded.
- Ctrl-C (or SIGTERM, SIGHUP): the tasks are cancelled (their judges killed with them), and the CSV holds the
  students graded, as locally.
"""
from __future__ import annotations

import os
import shutil
import signal
import socket
import sys
import tempfile
import time
from dataclasses import replace

from robot_ai import fleet
from robot_ai.grading import candidates, sandbox
from robot_ai.grading.class_run import ClassRun, Judges, Judging, dead_work_folders

MAX_RETRIES = 3           # runs of a student's task after the first when its node or worker dies
IN_FLIGHT_PER_CPU = 2     # tasks submitted ahead per CPU of the cluster
CANCEL_WAIT = 10.0        # seconds the cancelled tasks are given to end their judges before the CSV is written
NOT_GRADED = 'not graded'
WORK_PREFIX = 'check_fk_ray_'   # a task's work folder in the node's /tmp: check_fk_ray_<worker pid>_<random>


def grade_on_node(judging: Judging, index: int, student: str, shown_folder: str, packed: sandbox.Packed,
                  cores: float, model_xml: str = '') -> tuple[candidates.Result | None, bytes]:
    """A Ray task: grade one student on this node, from its folder as data and the model's URDF as text (the model
    file and its xacro includes need not exist on this machine: the URDF this side expanded is graded, and the
    report names the model as the user gave it); (the result, the report's bytes)."""
    t = time.time()
    shown = sandbox.printable(student)
    problem = sandbox.unavailable() if judging.sandboxed else ''
    if problem:
        line = f'{NOT_GRADED}: Ray node {socket.gethostname()} cannot grade in a sandbox: {problem}'
        return candidates.Result(shown, line, '', '', time.time() - t), (line + '\n').encode()
    _sweep()
    work = tempfile.mkdtemp(prefix=f'{WORK_PREFIX}{os.getpid()}_')
    os.chmod(work, 0o711)
    judges = Judges(judging, cores, work, die_with_parent=True)
    try:
        if model_xml:
            judges.judging = _on_this_machine(judging, model_xml, work)
        original = os.path.join(work, 'submitted')
        sandbox.unpack_folder(packed, original)
        report = os.path.join(work, 'report.txt')
        result = judges.one(index, student, original, shown_folder, report, hide=[work])
        try:
            with open(report, 'rb') as f:
                data = f.read()
        except OSError:
            data = b''
        return result, data
    finally:                     # done, cancelled (a KeyboardInterrupt) or failed: no judge or group outlives the task
        judges.stop()
        shutil.rmtree(work, ignore_errors=True)


def dead_workers_folders() -> list[str]:
    """The work folders (a student's copy, a judge's mount point) of this machine's tasks whose worker is gone: killed
    before its clean-up (a worker or a node killed mid-class)."""
    return dead_work_folders(WORK_PREFIX)


def _sweep() -> None:
    for folder in dead_workers_folders():
        shutil.rmtree(folder, ignore_errors=True)


def _on_this_machine(judging: Judging, model_xml: str, work: str) -> Judging:
    """The judging with the model written here: --model names the file, --xacro-args are spent (the URDF is expanded),
    --judge-model keeps the name the user gave."""
    path = os.path.join(work, 'model.urdf')
    with open(path, 'w') as f:
        f.write(model_xml)
    os.chmod(path, 0o644)
    options = list(judging.options)
    shown = options[options.index('--model') + 1]
    options[options.index('--model') + 1] = path
    options[options.index('--xacro-args') + 1] = ''
    return replace(judging, options=tuple(options) + ('--judge-model', shown))


def grade_class_on_ray(a, tree, xml: str) -> int:
    """--candidates DIR --ray ADDRESS: the class graded on the Ray cluster at a.ray (tree and xml: the model as
    check_fk read it); the same lines, reports and CSV as robot_ai.grading.class_run.grade_class's. A signal at any
    point once the class is read (connecting to a loaded cluster takes seconds) writes the CSV, every student not yet
    graded named so, and exits with the signal's status."""
    run = ClassRun.of(a, tree)
    if run is None:
        return 2
    results, pending = {}, {}
    ray = None
    begun = False
    stopped = None
    signals = []

    def on_signal(signum, frame):
        if not signals:
            signals.append(signum)
            raise SystemExit(128 + signum)
    stops = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    previous = {sig: signal.signal(sig, on_signal) for sig in stops}
    try:
        try:
            ray = fleet.connect(a.ray)
        except fleet.FleetError as e:
            print(f'check_fk: {e}', file=sys.stderr)
            return 2
        for sig in stops:                 # ray.init sets a SIGTERM handler of its own
            signal.signal(sig, on_signal)
        nodes = fleet.cluster_cpus(ray)
        if not nodes:
            print(f'check_fk: the Ray cluster at {a.ray} has no node with a CPU', file=sys.stderr)
            return 2
        begun = True
        _grade(ray, run, a, tree, xml, nodes, results, pending)
    except BaseException as e:   # a signal: the tasks are cancelled, none starts, the CSV is written
        # Ray's wait turns what a signal handler raises into SystemExit(1), and its own SIGTERM handler exits 15: the
        # status is the signal's, as a local run's
        stopped = SystemExit(128 + signals[0]) if signals else e
    finally:
        refs = list(pending)
        for ref in refs:
            try:
                ray.cancel(ref)
            except Exception:
                pass
        if refs:
            try:
                ray.wait(refs, num_returns=len(refs), timeout=CANCEL_WAIT)
            except BaseException:
                pass
        if begun or stopped is not None:
            run.write_csv(results)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return run.summary(results, stopped)


def _grade(ray, run: ClassRun, a, tree, xml: str, nodes: dict[str, float], results: dict, pending: dict) -> None:
    """The class's tasks on the cluster's nodes (their CPUs), a window of them in flight; each verdict recorded as
    its task returns. pending: the tasks in flight, for the caller to cancel when stopped."""
    smallest = min(nodes.values())
    cpus = smallest / a.jobs if a.jobs else 1.0        # --jobs: students per node at once (the smallest node's)
    cores = max(1.0, cpus)
    total = sum(nodes.values())
    run.prepare_reports()
    each = f'{a.jobs} per node' if a.jobs else 'one per CPU'
    run.header(a, tree, f'on the Ray cluster at {a.ray} ({len(nodes)} nodes, {total:g} CPUs, {each})',
               f'at most {cores:g} cores', 1)
    run.start_csv()
    model_xml = ray.put(xml)              # once for the class: every task reads it
    task = ray.remote(grade_on_node).options(num_cpus=cpus, max_retries=MAX_RETRIES, retry_exceptions=False)
    window = max(2, int(IN_FLIGHT_PER_CPU * total / cpus))
    waiting = list(enumerate(run.students))
    while waiting or pending:
        while waiting and len(pending) < window:
            index, student = waiting.pop(0)
            shown_folder = os.path.join(run.folder, student)
            t = time.time()
            try:
                packed = sandbox.pack(shown_folder)        # a folder, or a student that is one file
            except (sandbox.SandboxError, OSError) as e:      # as a local run's copy says it
                what = 'folder' if os.path.isdir(shown_folder) else 'file'
                result = candidates.Result(
                    sandbox.printable(student), f'FAIL: its {what} cannot be graded: {sandbox.printable(str(e))}',
                    run.judging.none_right, '', time.time() - t, 0.0)
                _record(run, results, index, student, result, b'')
                continue
            if not os.path.isdir(shown_folder):            # its file, unpacked there as a folder of it alone
                shown_folder = run.folder
            ref = task.remote(run.judging, index, student, shown_folder, packed, cores, model_xml)
            pending[ref] = (index, student, t)
        done, _ = ray.wait(list(pending), num_returns=1, timeout=1.0) if pending else ([], [])
        for ref in done:
            index, student, t = pending.pop(ref)
            try:
                result, report = ray.get(ref)
            except ray.exceptions.RayError as e:     # its retries spent, or an error of the task's own
                why = sandbox.printable(str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__)
                line = f'{NOT_GRADED}: its Ray task failed ({type(e).__name__}: {why})'
                result, report = candidates.Result(sandbox.printable(student), line, '', '', time.time() - t), \
                    (line + '\n').encode()
            if result is not None:
                _record(run, results, index, student, result, report)


def _record(run: ClassRun, results: dict, index: int, student: str, result: candidates.Result,
            report: bytes) -> None:
    """A student's verdict, once: its report file (where a judge ran, as locally), its line, its place in the CSV."""
    if student in results:
        return
    if report:
        try:
            with open(run.report_path(index, student), 'wb') as f:
                f.write(report)
        except OSError:
            pass
    results[student] = result
    run.record(student, result)
