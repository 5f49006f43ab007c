import os
import signal
import sys

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), '..')))

# The Ctrl-Cs the tests send (SIGINT to a process group) must reach their processes as a terminal's does. A shell that
# runs make test in the background (a CI job, `make test &`) starts it with SIGINT ignored, which every child then
# inherits: a SIGINT to the xacro expander was ignored and its test waited 30 s, in the workers of pytest -n 2 that
# had not run a test setting a handler first. A handled signal is reset to the default in a child at exec.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
