"""A simulator's lease: one env drives it at a time (cartpole_sim, arm_sim hold it; robot_ai.envs take it). rospy.

    lease = Lease('cartpole_sim')
    rospy.Service('~lease', robot_ai.srv.Lease, lease.handle)
    if not lease.allows(caller_of(msg)): ...          # a force, a command or a reset from someone else

The holder is a token (the env's node name and an id within its process: two envs of one process are two holders)
and its node (the request's sender, as the master knows it). The lease holds across pauses of any length; it ends
with a release, or once the holder's node no longer answers (its process died: a SIGKILL leaves its name at the
master, but its XML-RPC server is gone), which is checked when someone else asks for the lease or sends a command
(at most every CHECK_EVERY seconds).
"""
from __future__ import annotations

import threading
import time
import xmlrpc.client

import rosgraph
import rospy

from robot_ai.srv import LeaseResponse

CHECK_EVERY = 1.0        # seconds between two liveness checks of the holder prompted by intruders
PING_TIMEOUT = 1.0       # seconds a liveness check waits for the holder's node


def caller_of(msg) -> str:
    """The node that sent a message or a service request (rospy's connection header)."""
    return getattr(msg, '_connection_header', {}).get('callerid', '')


def node_alive(name: str, timeout: float = PING_TIMEOUT) -> bool:
    """Whether a node's process still runs at the address the master has for it (False: unknown to the master, or
    its port refuses: the process is gone). A process that is stopped (Ctrl-Z, a debugger) or busy for seconds in C
    code holding the GIL (a pickle save) still owns its port: the kernel accepts the connection and the answer is
    only late, so a timeout means alive, however long the pause."""
    try:
        uri = rosgraph.Master(rospy.get_name()).lookupNode(name)
    except rosgraph.MasterError:       # the master does not know it (any more)
        return False
    except Exception:                  # no master: nothing can be said against the holder
        return True
    try:
        code, _, _ = xmlrpc.client.ServerProxy(uri, transport=_Transport(timeout)).getPid(rospy.get_name())
        return code == 1
    except TimeoutError:               # connected, no answer yet: paused or busy, not gone
        return True
    except (OSError, xmlrpc.client.Error):   # refused, reset, unreachable: its process is gone
        return False


class _Transport(xmlrpc.client.Transport):
    """XML-RPC over HTTP with a timeout (a node that is stopped does not hold the caller)."""

    def __init__(self, timeout: float):
        super().__init__()
        self.timeout = timeout

    def make_connection(self, host):
        connection = super().make_connection(host)
        connection.timeout = self.timeout
        return connection


class Lease:
    """Who drives a simulator (see the module's docstring)."""

    def __init__(self, what: str):
        self.what = what
        self.lock = threading.Lock()
        self.token = ''
        self.node = ''
        self.since = 0.0
        self._checked = 0.0

    @property
    def held(self) -> bool:
        return bool(self.token)

    def describe(self) -> str:
        return f'{self.token} (node {self.node}, since {time.strftime("%H:%M:%S", time.localtime(self.since))})'

    def handle(self, req) -> LeaseResponse:
        """The ~lease service."""
        caller = caller_of(req)
        token = req.token or caller
        with self.lock:
            if req.release:
                if self.token and self.token == token:
                    self.token = self.node = ''
                    rospy.loginfo(f'{self.what}: lease released by {token}')
                    return LeaseResponse(success=True, message='released', holder='')
                return LeaseResponse(success=False, message=f'{token} holds no lease here', holder=self.token)
            if self.token and self.token != token:
                if node_alive(self.node):
                    return LeaseResponse(success=False, message=f'{self.what} is leased to {self.describe()}',
                                         holder=self.token)
                rospy.loginfo(f'{self.what}: the lease of {self.token} ended: its node {self.node} is gone')
            if self.token != token:
                rospy.loginfo(f'{self.what}: leased to {token}')
                self.token, self.node, self.since = token, caller, time.time()
            return LeaseResponse(success=True, message=f'leased to {token}', holder=token)

    def allows(self, caller: str) -> bool:
        """Whether a command or a reset from caller may act: no lease, or the holder's node; an intruder prompts a
        check (at most every CHECK_EVERY s) that the holder still runs, and a gone holder's lease ends."""
        with self.lock:
            if not self.token or caller == self.node:
                return True
            now = time.monotonic()
            if now - self._checked < CHECK_EVERY:
                return False
            self._checked = now
            node = self.node
        if node_alive(node):
            return False
        with self.lock:
            if self.node == node:
                rospy.loginfo(f'{self.what}: the lease of {self.token} ended: its node {node} is gone')
                self.token = self.node = ''
            return not self.token or caller == self.node

    def refusal(self, caller: str) -> str:
        return f'refused: {self.what} is leased to {self.describe()}, not {caller or "an unnamed node"}'
