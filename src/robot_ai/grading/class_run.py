"""A class graded at once: each student's node judged by a check_fk of its own in a sandbox (robot_ai.grading.sandbox),
--jobs at a time, one line per student, the CSV; and a single candidate judged the same way (--sandbox). No rospy:
the judge is ``robot_ai.nodes.check_fk`` in a process of its own, whose result comes back through a pipe only it
holds.

    status = grade_class(args, tree, argv)        # args: check_fk's parsed options (--candidates DIR, ...)
    status = reexec_in_namespaces(args, argv)     # --candidate FILE --sandbox
"""
from __future__ import annotations

import ctypes
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass

from robot_ai.child_process import PR_SET_PDEATHSIG, prctl
from robot_ai.grading import candidates, cgroups, sandbox
from robot_ai.grading.gradebook import Gradebook
from robot_ai.grading.processes import CHUNK, LOG_BYTES, free_port, signal_group
from robot_ai.grading.report import MAX_NAME, RESULT_BYTES, budget_of, nothing_graded

WALL_LIMIT_FACTOR = 3             # a judge is killed past this many times its budget of wall time, and a minute
JUDGE_MEMORY = 1024 ** 3          # bytes a judge (check_fk, its roscore and rosout) may use beside its student's
GROUP_TASKS = 1024                # processes and threads of a student's group: its own and its judge's
REPORT_TAIL = 64 * 1024        # bytes of a judge's report a class run keeps in memory
JUDGE = 'import sys; from robot_ai.nodes.check_fk import main; sys.exit(main(sys.argv[1:]))'
CLASS_WORK = 'check_fk_class_'    # a class run's work folder in /tmp: check_fk_class_<grader pid>_<random>
SANDBOX_WORK = 'check_fk_sandbox_'   # a --sandbox check's


def work_folder(prefix: str) -> str:
    """A work folder of this process's in /tmp (the students' copies, the judges' mount points), named with its pid so
    that a later run removes it if this one is killed before it can (dead_work_folders)."""
    for folder in dead_work_folders(prefix):
        shutil.rmtree(folder, ignore_errors=True)
    return tempfile.mkdtemp(prefix=f'{prefix}{os.getpid()}_')


def dead_work_folders(prefix: str) -> list[str]:
    """The work folders named `<prefix><pid>_...` in /tmp whose process is gone: a grader or a Ray worker killed (a
    SIGKILL, an out-of-memory kill) before its clean-up."""
    import glob
    out = []
    for folder in glob.glob(os.path.join(tempfile.gettempdir(), prefix + '*')):
        pid = os.path.basename(folder)[len(prefix):].split('_')[0]
        if pid.isdigit() and not os.path.exists(f'/proc/{pid}'):
            out.append(folder)
    return out


def sandboxed(a) -> bool:
    return a.judge_uid >= 0


def judge_env(home: str) -> dict:
    """A judge's environment: ROS on loopback (its network namespace has nothing else); home: the mount point of its
    logs (sandbox.private_ros_home), which the grader made (judge_home)."""
    env = {k: v for k, v in os.environ.items() if k not in ('ROS_IP', 'ROS_HOSTNAME', 'ROS_MASTER_URI')}
    env.update(ROS_HOSTNAME='127.0.0.1', ROS_MASTER_URI='http://127.0.0.1:11311', **{sandbox.JUDGE_HOME: home})
    return env


def judge_home(work: str) -> str:
    """A judge's mount point for its logs, made by its grader in its work folder: the judge mounts a tmpfs there in
    its own mount namespace, so that here it stays an empty folder, removed with the work folder however the judge
    ended (a judge that made its own in /tmp and was killed mid-grade left it there)."""
    return tempfile.mkdtemp(prefix='check_fk_judge_', dir=work)


def remove_judge_home(home: str) -> None:
    try:
        os.rmdir(home)
    except OSError:
        pass


def reexec_in_namespaces(a, argv) -> int:
    """--candidate with --sandbox: this check again as a judge in a network, PID and mount namespace of its own
    (its own master, the candidate as a user of its own, a copy of its folder); its exit status."""
    uid = sandbox.uid_for(os.getpid(), 0)
    work = work_folder(SANDBOX_WORK)
    home = judge_home(work)
    candidate, folder = a.candidate, ''
    try:
        if os.path.isfile(a.candidate):
            source = os.path.abspath(a.candidate)
            folder = os.path.join(work, 'student')
            try:
                sandbox.copy_folder(os.path.dirname(source), folder, uid)
            except (sandbox.SandboxError, OSError) as e:   # ~/solution.py: its folder is a home, not a submission
                shutil.rmtree(folder, ignore_errors=True)
                alone = os.path.join(work, 'alone')
                os.mkdir(alone)
                shutil.copy2(source, alone)
                sandbox.copy_folder(alone, folder, uid)
                print(f'check_fk: the sandbox holds {sandbox.printable(os.path.basename(source))} alone: its folder '
                      f'cannot be copied ({sandbox.printable(str(e))})', flush=True)
            candidate = os.path.join(folder, os.path.basename(source))
        words = argv + ['--candidate', candidate]   # the last --candidate is argparse's: the copy
        cmd = sandbox.judge_prefix() + [sys.executable, '-c', JUDGE] + words + [
            '--judge-uid', str(uid), '--judge-folder', folder, '--judge-hide', work, '--judge-shown', a.candidate]
        proc = subprocess.Popen(cmd, env=judge_env(home), preexec_fn=_as_a_fresh_process)   # dies with this one
        try:
            return proc.wait()
        except BaseException:
            proc.kill()
            proc.wait()
            raise
    finally:
        shutil.rmtree(work, ignore_errors=True)


class Reader:
    """A judge's stdout, drained by a thread: its last REPORT_TAIL bytes kept, the whole (up to LOG_BYTES) written to
    a report file."""

    def __init__(self, stream, path: str):
        self.tail = b''
        self.path = path
        self.thread = threading.Thread(target=self._drain, args=(stream,), daemon=True)
        self.thread.start()

    def _drain(self, stream) -> None:
        written = 0
        try:
            report = open(self.path, 'wb')
        except OSError:
            report, self.path = None, ''
        while True:
            try:
                chunk = os.read(stream.fileno(), CHUNK)
            except OSError:
                break
            if not chunk:
                break
            self.tail = (self.tail + chunk)[-REPORT_TAIL:]
            if report is not None and written < LOG_BYTES:
                report.write(chunk[:LOG_BYTES - written])
                written += len(chunk)
        if report is not None:
            report.close()

    def append(self, lines: list[str]) -> None:
        """Lines the class run adds at the end of the report, once the judge's output has ended."""
        self.thread.join(5.0)
        if self.path:
            with open(self.path, 'a') as report:
                report.write(''.join(line + '\n' for line in lines))

    def last_lines(self, n: int = 3) -> str:
        self.thread.join(5.0)
        lines = self.tail.decode(errors='replace').strip().splitlines()[-n:]
        return ' | '.join(sandbox.printable(line, 200) for line in lines)


def read_result(fd: int) -> dict | None:
    """A judge's result from the read end of its pipe (at most RESULT_BYTES), None when there is none or it is not
    the JSON a judge writes."""
    import json
    data = b''
    try:
        while len(data) <= RESULT_BYTES:
            chunk = os.read(fd, RESULT_BYTES)
            if not chunk:
                break
            data += chunk
    except OSError:
        return None
    finally:
        os.close(fd)
    try:
        result = json.loads(data.decode())
    except ValueError:
        return None
    if not isinstance(result, dict) or not all(isinstance(result.get(k), str) for k in
                                               ('verdict', 'score', 'first_wrong_link')):
        return None
    return result


@dataclass(frozen=True)
class Judging:
    """What every student's judge of a class run is given, the same on each machine that grades one (a record that
    travels to a Ray node as it is)."""
    options: tuple[str, ...]        # check_fk's options for each judge: the model, the configurations, the budget
    sandboxed: bool                 # false: --no-sandbox
    limit: float                    # wall-clock seconds past which a judge is killed with its namespaces
    limits: sandbox.Limits
    none_right: str                 # a student's score when nothing ran


class Judges:
    """The judges of one class run on this machine: each student's judge started, waited for and cleaned up, in a
    control group of its own where the machine has them; stop() ends every judge still running, and none starts after.

        judges = Judges(judging, cores=1.0, work=tempfile.mkdtemp())
        result = judges.one(index, student, folder_on_this_machine, folder_as_shown, report_path, hide=[...])
    """

    def __init__(self, judging: Judging, cores: float, work: str, die_with_parent: bool = False):
        # die_with_parent: the judges of a Ray task (robot_ai.grading.on_ray), which end with its worker
        self.judging, self.cores, self.work, self.die_with_parent = judging, cores, work, die_with_parent
        self.share = cgroups.version() if judging.sandboxed else 0
        if self.share:
            cgroups.sweep()           # the groups of graders and Ray workers killed before they could remove them
        self.running, self.groups, self.lock, self.stopping = {}, {}, threading.Lock(), []

    def stop(self) -> None:
        """No judge starts from now on; those running are killed with their groups (their students: not graded), and
        no group of this process's is left behind."""
        with self.lock:
            self.stopping.append(True)
            left = list(self.running.values())
        for proc in left:
            signal_group(proc.pid, signal.SIGKILL)
        for group in list(self.groups.values()):
            group.kill()
        if self.share:
            cgroups.sweep(maker=os.getpid())

    def one(self, index: int, student: str, original: str, shown_folder: str, report_path: str,
            hide: list[str]) -> candidates.Result | None:
        """Grade the student folder at `original` (named as `shown_folder` in the report); the report goes to
        report_path; `hide`: folders the student must not see. None when stopped."""
        j = self.judging
        t = time.time()         # from the first look at the folder: the CSV's seconds are the student's whole cost
        shown = sandbox.printable(student)
        no_node = 'FAIL: no node found (no Python file that calls rospy.init_node)'
        cmd, env, copy, home = [sys.executable, '-c', JUDGE] + list(j.options), None, '', ''
        if not os.path.isdir(original):      # a student that is one file (an LMS's flat download): a folder of it
            alone = os.path.join(self.work, f'file_{index}')
            try:
                sandbox.unpack_folder(sandbox.pack_file(original), alone)
            except (sandbox.SandboxError, OSError) as e:
                shutil.rmtree(alone, ignore_errors=True)
                return candidates.Result(shown, f'FAIL: its file cannot be graded: {sandbox.printable(str(e))}',
                                         j.none_right, '', time.time() - t, 0.0)
            original, shown_folder = alone, os.path.dirname(shown_folder)
        if not j.sandboxed:
            node = candidates.find_node(original)
            if node is None:
                return candidates.Result(shown, no_node, j.none_right, '', time.time() - t, 0.0)
            env = dict(os.environ, ROS_MASTER_URI=f'http://127.0.0.1:{free_port()}')   # none runs there: its own
            cmd += ['--candidate', node, '--judge-shown', os.path.join(shown_folder, os.path.relpath(node, original))]
            source = os.path.basename(node)
        else:
            # the folder is counted and copied first (links kept as links, nothing else but files and folders), and
            # the node is looked for in the copy: nothing of the student's is read before it is bounded
            uid = sandbox.uid_for(os.getpid(), index)
            copy = os.path.join(self.work, str(index))
            try:
                sandbox.copy_folder(original, copy, uid)
            except (sandbox.SandboxError, OSError) as e:
                shutil.rmtree(copy, ignore_errors=True)
                return candidates.Result(shown, f'FAIL: its folder cannot be graded: {sandbox.printable(str(e))}',
                                         j.none_right, '', time.time() - t, 0.0)
            found = candidates.find_node(copy)
            if found is None:
                shutil.rmtree(copy, ignore_errors=True)
                return candidates.Result(shown, no_node, j.none_right, '', time.time() - t, 0.0)
            node = os.path.join(shown_folder, os.path.relpath(found, copy))     # as the student named it
            source = os.path.basename(found)
            cmd = sandbox.judge_prefix() + cmd + [
                '--candidate', found, '--judge-uid', str(uid), '--judge-shown', node, '--judge-folder', copy]
            for folder in hide:
                cmd += ['--judge-hide', folder]
            home = judge_home(self.work)
            env = judge_env(home)
            if self.share:
                group = cgroups.Group.create(f'check_fk_{os.getpid()}_{index}', self.cores,
                                             j.limits.memory_bytes + JUDGE_MEMORY, GROUP_TASKS)
                if group is not None:
                    self.groups[student] = group
                    cmd = group.exec_prefix(sys.executable) + cmd + ['--judge-pressure', group.pressure_file]
        read_end, write_end = os.pipe()
        try:
            with self.lock:
                if self.stopping:
                    os.close(read_end)
                    if copy:
                        shutil.rmtree(copy, ignore_errors=True)
                    if home:
                        remove_judge_home(home)
                    return None
                # a Ray worker that is killed takes its judge (and with unshare's --kill-child, the namespaces)
                proc = subprocess.Popen(cmd + ['--result-fd', str(write_end)], env=env, stdout=subprocess.PIPE,
                                        stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True,
                                        pass_fds=(write_end,),
                                        preexec_fn=_as_a_fresh_process if self.die_with_parent else None)
                self.running[student] = proc
        finally:
            os.close(write_end)
        reader = Reader(proc.stdout, report_path)
        ended = False
        try:
            deadline = time.monotonic() + j.limit
            while True:       # in slices: a Ray task's cancel (a KeyboardInterrupt) is seen between them
                try:
                    proc.wait(timeout=min(1.0, max(0.0, deadline - time.monotonic())))
                    timed_out = False
                    break
                except subprocess.TimeoutExpired:
                    if time.monotonic() >= deadline:
                        signal_group(proc.pid, signal.SIGKILL)       # unshare, and with it the judge's namespaces
                        proc.wait()
                        timed_out = True
                        break
            ended = True
        finally:
            if not ended:     # interrupted (a cancel, a signal): the judge goes with whatever stopped the wait
                signal_group(proc.pid, signal.SIGKILL)
                proc.wait()
                os.close(read_end)
                if copy:
                    shutil.rmtree(copy, ignore_errors=True)
            with self.lock:
                self.running.pop(student, None)
            group = self.groups.pop(student, None)
            if group is not None:     # whatever its judge or the student left: ended, and the group removed
                group.kill()
                group.remove()
            if home:
                remove_judge_home(home)
        result = read_result(read_end)
        if copy:
            shutil.rmtree(copy, ignore_errors=True)
        seconds = time.time() - t
        if self.stopping and (result is None or proc.returncode < 0):
            return None
        if timed_out or result is None:    # the judge's own report ends without them: they are added to it
            verdict = (f'FAIL: grading did not end within {j.limit:.0f} s of wall time ({WALL_LIMIT_FACTOR} times its '
                       f'budget and a minute): ended' if timed_out
                       else f'FAIL: check_fk ended with status {proc.returncode} and no result: '
                            f'{reader.last_lines()}')
            reader.append([f'score: {j.none_right}', 'grade: 0.0', verdict])
            return candidates.Result(shown, verdict, j.none_right, '', seconds, 0.0, source)
        reader.thread.join(5.0)
        verdict = sandbox.printable(result['verdict'], 600, backslashes=False)
        grade = result.get('grade')
        grade = float(grade) if isinstance(grade, (int, float)) and 0 <= grade <= 100 else 0.0
        if verdict.startswith('PASS') != (proc.returncode == 0):
            verdict = f'FAIL: check_fk said {verdict[:200]} but ended with status {proc.returncode}'
            grade = min(grade, 99.9)
        judged = result.get('seconds')      # one duration per student: the judge's own, which its report says too
        if isinstance(judged, (int, float)) and 0 <= judged <= seconds:
            seconds = float(judged)
        return candidates.Result(shown, verdict, sandbox.printable(result['score'], 100, backslashes=False),
                                 sandbox.printable(result['first_wrong_link'], MAX_NAME, backslashes=False), seconds,
                                 grade, source)


_LIBC = ctypes.CDLL(None, use_errno=True)
_LIBC.signal.restype = ctypes.c_void_p
_LIBC.signal.argtypes = [ctypes.c_int, ctypes.c_void_p]


def _as_a_fresh_process() -> None:
    """A judge started by a Ray worker (in the child, before exec): killed with the worker, and with the signals a
    terminal's process has: a Ray worker blocks and ignores SIGINT, and a judge (and the roscore and the student it
    starts) would inherit both, so that its clean-up waited out every SIGINT's timeout."""
    prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    signal.pthread_sigmask(signal.SIG_SETMASK, [])
    for sig in (signal.SIGINT, signal.SIGQUIT):
        _LIBC.signal(sig, None)      # SIG_DFL


@dataclass
class ClassRun:
    """What a class run is, wherever its students are graded: the students (folder names, sorted), where the CSV and
    the reports go, the judges' record; header() prints what is graded, write_csv() and summary() end it."""
    folder: str
    students: list[str]
    csv_path: str
    reports: str
    judging: Judging
    budget: float
    book: Gradebook

    @classmethod
    def of(cls, a, tree) -> ClassRun | None:
        """check_fk's options -> the run; None (after one line on stderr) for a folder without student folders."""
        folder = os.path.abspath(a.candidates)
        students = sorted(d for d in os.listdir(folder) if d[0] != '.' and (
            os.path.isdir(os.path.join(folder, d)) or candidates.is_python(os.path.join(folder, d))))
        if not students:
            print(f'check_fk: {folder} has no student folders (nor Python files, one per student)', file=sys.stderr)
            return None
        budget = budget_of(a)
        path = a.csv or f'check_fk_{os.path.basename(folder)}.csv'
        reports = os.path.splitext(os.path.abspath(path))[0] + '_reports'
        options = ('--model', a.model, '--xacro-args', a.xacro_args, '--configurations', str(a.configurations),
                   '--seed', str(a.seed), '--tolerance', repr(a.tolerance), '--timeout', repr(a.timeout),
                   '--budget', repr(budget), '--expect', 'pass')
        # the judge's budget counts the time its student was given a CPU (cgroups.BudgetClock): on a loaded machine
        # that is less than wall time, so the wall-clock limit past which a judge is killed with its namespaces is wider
        judging = Judging(options, not a.no_sandbox, WALL_LIMIT_FACTOR * budget + 60.0,
                          sandbox.Limits(cpu_seconds=int(budget) + 60),
                          nothing_graded(tree, a.configurations)[len('score: '):])
        book = Gradebook(path, a.csv_format, students, a.id_from, a.assignment)
        return cls(folder, students, path, reports, judging, budget, book)

    def prepare_reports(self) -> None:
        os.makedirs(self.reports, exist_ok=True)
        for old in os.listdir(self.reports):        # an earlier run's reports: this run's numbering may differ
            if old[:3].isdigit() and old[3:4] == '_' and old.endswith('.txt'):
                os.remove(os.path.join(self.reports, old))

    def report_path(self, index: int, student: str) -> str:
        return os.path.join(self.reports, f'{index:03d}_{_file_name(student)}.txt')

    def header(self, a, tree, where: str, cores: str, share: int) -> None:
        """The lines that open a run: the class, the model, the checks, where the students are graded (`where`: 'N at
        a time'), the sandbox and the control groups (`cores`: each student's CPU share, in words)."""
        on_model = f'{a.model}' + (f' with xacro arguments "{a.xacro_args}"' if a.xacro_args else '')
        limits = self.judging.limits
        print(f'check_fk: {len(self.students)} students in {sandbox.printable(self.folder)} on {on_model} '
              f'({len(tree.links)} links), {a.configurations} configurations (seed {a.seed}, tolerance '
              f'{a.tolerance:g}, timeout {a.timeout:g} s), at most {self.budget:g} s each, {where}')
        if not self.judging.sandboxed:
            print('check_fk: NOT sandboxed (--no-sandbox): every student runs as you, with your files and network')
        else:
            print(f'check_fk: each student in a sandbox: a user of its own, a copy of its folder, a network of its '
                  f'own, {limits.describe()}')
            print(f'check_fk: each student and its judge in a control group of their own: an equal CPU share ({cores}'
                  f'), {(limits.memory_bytes + JUDGE_MEMORY) / 1024 ** 3:g} GiB of memory together, {GROUP_TASKS} '
                  f'tasks; the budget counts the time a CPU was given' if share else
                  'check_fk: no control groups here (cgroup v1 or v2 with root): limits are per process')
        print(f'check_fk: reports in {self.reports}', flush=True)

    def start_csv(self) -> None:
        """The CSV's header, on disk before any student is graded; rows follow as verdicts come (record)."""
        self.book.start()

    def record(self, student: str, result: candidates.Result) -> None:
        """A student's line, and its row in the CSV on disk: a grader killed from now on has lost none of it."""
        print(result.line(), flush=True)
        self.book.add(student, result)

    def write_csv(self, results: dict) -> None:
        """The CSV at the end: one row per student in the folder's sorted order; a student without a result: not
        graded."""
        self.book.finish(results)

    def summary(self, results: dict, stopped: BaseException | None) -> int:
        """The last line (the students graded and not, when stopped) and the exit status; a stop is raised again."""
        passed = sum(r.verdict.startswith('PASS') for r in results.values())
        if stopped is not None:
            rest = [sandbox.printable(s) for s in self.students if s not in results]
            print(f'check_fk: stopped: {len(results)} of {len(self.students)} graded ({passed} PASS); CSV: '
                  f'{os.path.abspath(self.csv_path)}; not graded: {", ".join(rest)}', flush=True)
            if isinstance(stopped, SystemExit):
                return stopped.code if isinstance(stopped.code, int) else 1
            raise stopped
        print(f'{passed} of {len(self.students)} PASS; CSV: {os.path.abspath(self.csv_path)}')
        return 0


def grade_class(a, tree, argv) -> int:
    """--candidates DIR: the node in each student folder of DIR graded by a judge of its own (a check_fk in a network,
    PID and mount namespace of its own, its own roscore; the student's node in a sandbox: see robot_ai.grading.sandbox),
    --jobs at a time; one line per student as each ends, then the CSV. A student's verdict is the judge's result and
    exit status, which the student's code cannot write; a crash, a hang or an escape attempt is that student's
    verdict and the others go on. A signal stops the run: the CSV holds the students graded, and the rest are named.
    0 once every student has a line. (With --ray: robot_ai.grading.on_ray, the same lines and CSV.)"""
    import concurrent.futures
    run = ClassRun.of(a, tree)
    if run is None:
        return 2
    jobs = a.jobs or os.cpu_count() or 1
    run.prepare_reports()
    work = work_folder(CLASS_WORK)
    os.chmod(work, 0o711)
    cores = max(1.0, (os.cpu_count() or 1) / jobs)          # each student's CPU share, at most
    # a grader killed with SIGKILL (an out-of-memory kill) takes its judges along: none grades on for nobody
    judges = Judges(run.judging, cores, work, die_with_parent=True)
    run.header(a, tree, f'{jobs} at a time', f'at most {cores:g} cores', judges.share)
    hide = [run.folder, run.reports, work]

    def one(index: int, student: str) -> candidates.Result | None:
        return judges.one(index, student, os.path.join(run.folder, student), os.path.join(run.folder, student),
                          run.report_path(index, student), hide)

    results = {}
    pool = concurrent.futures.ThreadPoolExecutor(max_workers=jobs)
    stopped = None
    try:
        run.start_csv()
        futures = {pool.submit(one, i, student): student for i, student in enumerate(run.students)}
        for future in concurrent.futures.as_completed(futures):
            result = future.result()
            if result is not None:
                results[futures[future]] = result
                run.record(futures[future], result)
    except BaseException as e:   # a signal: the students being graded are stopped, none starts, the CSV is written
        stopped = e
    finally:
        judges.stop()
        pool.shutdown(wait=True, cancel_futures=True)
        shutil.rmtree(work, ignore_errors=True)
        run.write_csv(results)
    return run.summary(results, stopped)


def _file_name(student: str) -> str:
    """A report file's name for a student folder's name: letters, digits, '.', '-' and '_' kept."""
    return ''.join(c if c.isalnum() or c in '.-_' else '_' for c in student)[:80] or 'student'
