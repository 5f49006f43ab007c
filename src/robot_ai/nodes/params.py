"""Private parameters read once at start: a value of the wrong kind falls back to the default with one warning
that names the parameter and says what is allowed, never a traceback; run_node for nodes whose bad parameters
end them with one line instead; init_node, whose Ctrl-C cannot deadlock rospy."""
import functools
import math
import signal
import threading
from typing import Callable

import rospy


def init_node(name: str, **kwargs) -> None:
    """rospy.init_node with rospy's Ctrl-C (SIGINT) and SIGTERM handling moved off the main thread. rospy shuts down
    inside its signal handler, on the main thread: a signal that lands while that thread is inside a call to the
    master (registering a service, say) makes the shutdown's own calls wait for the master proxy's lock, which the
    interrupted call holds, so the node deadlocks and ignores SIGINT and SIGTERM until roslaunch's SIGKILL 17 s later
    (a Ctrl-C 2 s into demo.launch, one launch in six on a loaded machine). Here the handler only starts a thread
    that shuts rospy down; the interrupted call completes and lets go of the lock."""
    def deferred(signum, _frame):
        threading.Thread(target=rospy.signal_shutdown, args=(f'signal-{signum}',), daemon=True).start()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, deferred)
    threading.excepthook = _quiet_server_shutdown
    rospy.init_node(name, disable_signals=True, **kwargs)


_THREAD_EXCEPTHOOK = threading.excepthook


def _quiet_server_shutdown(args) -> None:
    """threading's hook for an exception that ends a thread, quiet for one race of rospy's (Debian's 1.15): a shutdown
    right after init_node closes the TCPROS server's socket before its accept thread has begun, whose run() then sets
    is_shutdown back to False and takes accept()'s OSError (bad file descriptor) for an error: a traceback on a
    Ctrl-C 2 s into demo.launch (launch.test, once in a fresh-clone run). Every other exception is threading's as
    before."""
    if (issubclass(args.exc_type, OSError)
            and any(frame.f_code.co_filename.endswith('rospy/impl/tcpros_base.py') for frame in _frames(args))
            and (rospy.core.is_shutdown_requested() or rospy.is_shutdown())):
        return
    _THREAD_EXCEPTHOOK(args)


def _frames(args):
    tb = args.exc_traceback
    while tb is not None:
        yield tb.tb_frame
        tb = tb.tb_next


def quiet_on_shutdown(main: Callable) -> Callable:
    """A node's main(), ended quietly by a Ctrl-C at any moment of its start: rospy then raises ROSInitException
    ("init_node interrupted") or ROSInterruptException out of whatever the node was doing; that is no error."""
    @functools.wraps(main)
    def wrapped(*args, **kwargs):
        try:
            return main(*args, **kwargs)
        except (rospy.ROSInitException, rospy.ROSInterruptException):
            if rospy.core.is_shutdown_requested() or rospy.is_shutdown():
                raise SystemExit(0)
            raise
    return wrapped


@quiet_on_shutdown
def run_node(name: str, build: Callable[[], object]) -> None:
    """init_node(name), build the node, spin; a bad parameter (a ValueError from build) ends it with one line."""
    init_node(name)
    try:
        build()
    except ValueError as e:  # robot_ai's RequestError and PolicyError are ValueErrors
        rospy.logfatal(f'{name}: bad parameter: {e}')
        raise SystemExit(1)
    rospy.spin()


def publish(publisher: rospy.Publisher, msg) -> None:
    """publisher.publish(msg); a message in flight while the node shuts down (Ctrl-C) is dropped quietly. rospy
    closes its topics in the hooks it runs once a shutdown is requested, before is_shutdown() becomes true."""
    try:
        publisher.publish(msg)
    except rospy.ROSException:
        if not (rospy.core.is_shutdown_requested() or rospy.is_shutdown()):
            raise


def number_param(name: str, default: float, allowed: str, valid: Callable[[float], bool]) -> float:
    """A numeric private parameter; a value that is not `allowed` falls back to the default with one warning."""
    value = rospy.get_param(name, default)
    try:
        number = float(value)
        if isinstance(value, bool) or not math.isfinite(number) or not valid(number):
            raise ValueError
    except (TypeError, ValueError):
        rospy.logwarn(f'{name} must be {allowed}, got {value!r}: using {default!r}')
        return default
    return number


def bool_param(name: str, default: bool) -> bool:
    """A boolean private parameter: true/false (or 1/0); anything else falls back to the default with a warning."""
    value = rospy.get_param(name, default)
    if isinstance(value, bool):
        return value
    if value in (0, 1) or str(value).lower() in ('true', 'false'):
        return value in (1, True) or str(value).lower() == 'true'
    rospy.logwarn(f'{name} must be true or false, got {value!r}: using {default!r}')
    return default


def int_param(name: str, default: int, allowed: str = 'a whole number of at least 1',
              valid: Callable[[float], bool] = lambda v: v >= 1) -> int:
    """An integer private parameter (see number_param)."""
    value = number_param(name, default, allowed, lambda v: v == int(v) and valid(v))
    return int(value)


def str_param(name: str, default: str) -> str:
    """A text private parameter; anything else falls back to the default with a warning."""
    value = rospy.get_param(name, default)
    if isinstance(value, str):
        return value
    rospy.logwarn(f'{name} must be text, got {value!r}: using {default!r}')
    return default


def numpy_service(service_class):
    """service_class with its request read by numpy: an array field is one array over the message's bytes, not a
    Python float per number (a ~set_state of 20 million numbers cost a sim 1.2 GB before its refusal; now about the
    message's 160 MB, given back with it). Same type and md5sum: callers see the same service."""
    from rospy.numpy_msg import numpy_msg
    return type(f'Numpy{service_class.__name__}', (), dict(
        _type=service_class._type, _md5sum=service_class._md5sum,
        _request_class=numpy_msg(service_class._request_class), _response_class=service_class._response_class))
