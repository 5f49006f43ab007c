"""A learner process of a Q-learning batch: ``python -m robot_ai.cartpole.learner_worker``, started by
q_learning.train through robot_ai.child_process.spawn (never forked). No rospy.

Frames on stdin (from the parent): ``('training', settings, batch_seed, start_agent_or_None)`` once, then
``('learner', j)`` for each learner to train; the end of stdin ends the process. Frames on stdout (to the
parent): ``('alive',)`` every HEARTBEAT_SECONDS from a thread of its own, from the process's start (a stopped or
hung process falls silent, and the parent notices),
``('episode', j, episode, total_reward, epsilon)`` after every episode, ``('done', j, agent, greedy_average)``
when learner j has played every episode. The process ends with its parent (SIGKILL: it has nothing to save; the
parent has every episode's total already), and its BLAS runs on one thread: each worker has a core of its own.
"""
import importlib
import os
import signal
import sys
import threading
import time
import warnings

HEARTBEAT_SECONDS = 0.5


def main() -> int:
    signal.signal(signal.SIGINT, signal.SIG_DFL)   # quiet: the parent, not a terminal, ends a worker
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    from robot_ai.child_process import die_with_parent, read_frame, write_frame
    die_with_parent(signal.SIGKILL)
    # The frames get stdout's pipe to themselves; anything a library prints goes to stderr.
    out = os.fdopen(os.dup(sys.stdout.fileno()), 'wb')
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    lock = threading.Lock()

    def send(message) -> None:
        try:
            with lock:
                write_frame(out, message)
        except (BrokenPipeError, OSError):  # the parent has gone: nothing is waiting for this learner
            os._exit(0)

    def heartbeat() -> None:
        while True:
            send(('alive',))
            time.sleep(HEARTBEAT_SECONDS)

    # From the start: the imports below take seconds on a loaded machine, and that is not silence.
    threading.Thread(target=heartbeat, name='heartbeat', daemon=True).start()
    from threadpoolctl import threadpool_limits
    from robot_ai.cartpole.dynamics import CartPoleDynamics
    from robot_ai.cartpole.q_learning import Training, greedy_average, train_one
    threadpool_limits(1)
    importlib.import_module('gymnasium')  # it sets its warning filters at import: ignore its deprecations after
    warnings.simplefilter('ignore', DeprecationWarning)  # CartPole-v0's: the parent has shown it

    first = read_frame(sys.stdin.buffer)
    if first is None:
        return 0
    _, settings, seed, start = first
    settings = dict(settings)
    training = Training(dynamics=CartPoleDynamics.of(settings.pop('env_id')), start=start, **settings)
    while (message := read_frame(sys.stdin.buffer)) is not None:
        j = message[1]
        _, agent = train_one(training, seed + j, lambda e, r, eps: send(('episode', j, e, r, eps)))
        send(('done', j, agent, greedy_average(agent, training, seed + j)))
    return 0


if __name__ == '__main__':
    sys.exit(main())
