"""The roscore of one FK check: ROS's own master (rosmaster) and rosout, with the parameter server bounded. No rospy.

A student's node talks to its judge's master, and a master keeps every parameter it is given: a student stored
1,200 MiB of parameters through it (issue 56) while its own processes kept within their limits. Here the parameters'
bytes are counted as they are set (a value's strings, numbers and containers) and a set that would take them past
PARAM_BYTES is refused: the caller gets the master's error, and the master writes who asked to the file `refused`,
which the judge reads for its verdict. An XML-RPC request larger than REQUEST_BYTES is refused before it is read.

    python -m robot_ai.grading.master PORT REFUSED_FILE     # what processes.start_master runs
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
import uuid

PARAM_BYTES = 64 * 1024 ** 2         # bytes of parameters the master keeps
REQUEST_BYTES = PARAM_BYTES + 1024 ** 2   # bytes of one XML-RPC request it reads
ITEM_BYTES = 16                      # a number, a boolean, a date: what a value without a length is counted as


def size_of(value, depth: int = 0) -> int:
    """The bytes a parameter value holds: its strings' and binaries' lengths, ITEM_BYTES per other item, its keys."""
    if depth > 100:              # XML-RPC nests no deeper than its parser lets it; a bound all the same
        return ITEM_BYTES
    if isinstance(value, (str, bytes, bytearray)):
        return len(value) + ITEM_BYTES
    if isinstance(value, dict):
        return ITEM_BYTES + sum(len(str(k)) + size_of(v, depth + 1) for k, v in value.items())
    if isinstance(value, (list, tuple)):
        return ITEM_BYTES + sum(size_of(v, depth + 1) for v in value)
    data = getattr(value, 'data', None)          # xmlrpc.client.Binary
    if isinstance(data, (bytes, bytearray)):
        return len(data) + ITEM_BYTES
    return ITEM_BYTES


class ParamBudget:
    """The bytes held under each key that was set, their total, and the first caller refused (written to a file)."""

    def __init__(self, limit: int, refused_file: str):
        self.limit, self.refused_file = limit, refused_file
        self.sizes, self.total, self.lock, self.refused = {}, 0, threading.Lock(), False

    def _under(self, key: str) -> list[str]:
        prefix = key.rstrip('/') + '/'
        return [k for k in self.sizes if k == key or k.startswith(prefix)]

    def set(self, key: str, value, caller: str) -> None:
        """Count key's new value in place of what was under it; ValueError past the limit (nothing changes)."""
        size = size_of(value)
        with self.lock:
            under = self._under(key)
            total = self.total - sum(self.sizes[k] for k in under) + size
            if total > self.limit:
                self.refuse(caller, f'setting {key[:200]} ({size} bytes) would hold {total} bytes of parameters')
                raise ValueError(f'this master holds at most {self.limit // 1024 ** 2} MiB of parameters '
                                 f'(check_fk\'s bound): {key[:200]} refused')
            for k in under:
                del self.sizes[k]
            self.sizes[key] = size
            self.total = total

    def delete(self, key: str) -> None:
        with self.lock:
            for k in self._under(key):
                self.total -= self.sizes.pop(k)

    def refuse(self, caller: str, what: str) -> None:
        if self.refused:
            return
        self.refused = True
        try:
            with open(self.refused_file, 'w') as f:
                json.dump(dict(caller=str(caller)[:200], what=what, limit=self.limit), f)
        except OSError:
            pass


def read_refused(path: str) -> dict | None:
    """What a master wrote when it refused a parameter (caller, what, limit), or None."""
    try:
        with open(path) as f:
            data = json.loads(f.read(4096))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and isinstance(data.get('caller'), str) else None


def bound(budget: ParamBudget) -> None:
    """rosmaster's parameter server and XML-RPC handler, bounded by budget (patched in this process only)."""
    import rosgraph.xmlrpc
    import rosmaster.master_api
    import rosmaster.paramserver

    dictionary = rosmaster.paramserver.ParamDictionary
    set_param, delete_param = dictionary.set_param, dictionary.delete_param

    def bounded_set(self, key, value, notify_task=None, caller_id=None):
        budget.set(key, value, caller_id or '')
        return set_param(self, key, value, notify_task, caller_id)

    def bounded_delete(self, key, notify_task=None):
        result = delete_param(self, key, notify_task)
        budget.delete(key)
        return result
    dictionary.set_param, dictionary.delete_param = bounded_set, bounded_delete

    handler = rosgraph.xmlrpc.SilenceableXMLRPCRequestHandler
    do_post = handler.do_POST

    def bounded_post(self):
        try:
            length = int(self.headers.get('content-length', 0))
        except ValueError:
            length = 0
        if length > REQUEST_BYTES:
            budget.refuse(self.client_address[0] if self.client_address else '',
                          f'an XML-RPC request of {length} bytes')
            self.send_error(413, 'request too large (check_fk\'s bound)')
            self.close_connection = True
            return
        return do_post(self)
    handler.do_POST = bounded_post


def versions() -> tuple[str, str]:
    """(rosversion roslaunch, rosversion -d), what roscore sets as /rosversion and /rosdistro."""
    out = []
    for words in (['rosversion', 'roslaunch'], ['rosversion', '-d']):
        try:
            out.append(subprocess.run(words, capture_output=True, text=True, timeout=30).stdout)
        except (OSError, subprocess.SubprocessError):
            out.append('')
    return out[0], out[1]


def main(argv: list[str]) -> int:
    port, refused_file = int(argv[0]), argv[1]
    import rosmaster.master
    import roslib.packages
    budget = ParamBudget(PARAM_BYTES, refused_file)
    bound(budget)
    master = rosmaster.master.Master(port)
    master.start()
    uri = f'http://127.0.0.1:{port}'
    rosout = None
    try:
        while not master.ok():
            time.sleep(0.01)
        handler = master.handler
        rosversion, rosdistro = versions()
        for key, value in (('/run_id', str(uuid.uuid1())), ('/rosversion', rosversion), ('/rosdistro', rosdistro)):
            handler.setParam('/roscore', key, value)
        found = roslib.packages.find_node('rosout', 'rosout')
        if found:
            rosout = subprocess.Popen([found[0], '__name:=rosout'], env=dict(os.environ, ROS_MASTER_URI=uri),
                                      stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        while master.ok():
            time.sleep(0.1)
    except KeyboardInterrupt:
        pass
    finally:
        if rosout is not None and rosout.poll() is None:
            rosout.terminate()
        master.stop()
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
