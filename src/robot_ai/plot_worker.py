"""A long-lived process that draws plots for the nodes, fed one JSON line per plot on stdin. No rospy.

The nodes hand plots to it instead of drawing them in a thread: matplotlib holds the GIL for tens of
milliseconds, which a thread in the node would take from the service answering a request.

    line = {"path": "/abs/file.png", "job": <a plot job of robot_ai.artifacts>}

For every line it prints ``written <path>`` on stdout, or ``failed <path>: <reason>`` on stderr, and goes on
with the next. It ends quietly, with status 0, at the end of its input, on SIGINT or SIGTERM, and when the node
that started it ends, however it ends (it gets a SIGTERM then; see robot_ai.child_process).
"""
import json
import signal
import sys


def job_line(job: dict, path: str) -> str:
    """The line that asks the plot process to draw job into path."""
    return json.dumps({'path': path, 'job': job}) + '\n'


def _quit(signum, frame):
    raise SystemExit(0)


def main() -> int:
    signal.signal(signal.SIGINT, _quit)
    signal.signal(signal.SIGTERM, _quit)
    try:
        from robot_ai.child_process import die_with_parent
        die_with_parent(signal.SIGTERM)  # started by a node (child_process.spawn): end with it, however it ends
        from robot_ai.artifacts import write_plot
        for line in sys.stdin:
            path = '?'
            try:
                request = json.loads(line)
                path = request['path']
                write_plot(request['job'], path)
                print(f'written {path}', flush=True)
            except Exception as e:  # one bad job must not stop the next ones
                print(f'failed {path}: {e}', file=sys.stderr, flush=True)
    except (SystemExit, BrokenPipeError):
        pass
    return 0


if __name__ == '__main__':
    sys.exit(main())
