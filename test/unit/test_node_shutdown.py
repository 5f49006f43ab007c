"""rospy's TCPROS server race on a Ctrl-C right after init_node (launch.test's Ctrl-C 2 s into demo.launch): a
shutdown that closes the server's socket before its accept thread has begun leaves that thread to raise accept()'s
OSError (bad file descriptor), a traceback in the launch's output. The nodes' init_node installs a thread exception
hook that keeps that one quiet during a shutdown and reports every other exception as threading does. No roscore:
rospy's own TCPServer, and the shutdown flag patched."""
import socket
import threading

import rospy
from rospy.impl.tcpros_base import TCPServer

from robot_ai.nodes import params


def race(hook, shutting_down: bool, monkeypatch) -> list:
    """The race replayed with hook as threading.excepthook: what the hook passed on to threading's own."""
    passed = []
    monkeypatch.setattr(params, '_THREAD_EXCEPTHOOK', passed.append)
    monkeypatch.setattr(rospy.core, 'is_shutdown_requested', lambda: shutting_down)
    monkeypatch.setattr(threading, 'excepthook', hook)
    server = TCPServer(lambda sock, addr: None, port=0)
    server.shutdown()                         # before the accept thread has begun: its run() resets is_shutdown
    thread = threading.Thread(target=server.run)
    thread.start()
    thread.join(5)
    assert not thread.is_alive()
    return passed


def test_the_servers_race_is_quiet_during_a_shutdown_and_reported_otherwise(monkeypatch):
    assert race(params._quiet_server_shutdown, True, monkeypatch) == []
    reported = race(params._quiet_server_shutdown, False, monkeypatch)
    assert len(reported) == 1 and issubclass(reported[0].exc_type, OSError)     # no shutdown: an error, as before


def test_other_exceptions_in_threads_are_reported_during_a_shutdown_too(monkeypatch):
    passed = []
    monkeypatch.setattr(params, '_THREAD_EXCEPTHOOK', passed.append)
    monkeypatch.setattr(rospy.core, 'is_shutdown_requested', lambda: True)
    monkeypatch.setattr(threading, 'excepthook', params._quiet_server_shutdown)

    def closed_socket():
        s = socket.socket()
        s.close()
        s.accept()                            # the same OSError, raised by the package's own code
    thread = threading.Thread(target=closed_socket)
    thread.start()
    thread.join(5)
    assert len(passed) == 1 and issubclass(passed[0].exc_type, OSError)
