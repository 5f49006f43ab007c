"""What every env over ROS needs before its first step: a node (never a hang without a master), a simulator of its
own (claimed by a lease), and the rule that only that simulator's answers count. rospy client code, no node.

    ensure_node(timeout)                                   # RosEnvError within timeout if no master answers
    ns = claim('cartpole_sim', token, timeout)             # the first free sim of the running ones, leased
    lease('/cartpole_3', 'cartpole_sim', token, timeout)   # that one, or RosEnvError naming its holder
    ns = take(ns, 'cartpole_sim', token, timeout, hint, unusable)     # ns's (checked), or claim's without one
    release('/cartpole_3', 'cartpole_sim', token)

A simulator (cartpole_sim, arm_sim) serves its ~lease (robot_ai.nodes.lease): it grants it to one token at a time
and, while leased, takes commands and resets from the holder's node only. The env then takes as the simulator's
answer only a message whose sender is the simulator's node and whose header.seq (rospy's count of the messages of
that publisher) is the one its own command produced.
"""
from __future__ import annotations

import itertools
import multiprocessing
import os
import re
import socket
import sys
import time
import urllib.parse

import rospy

DEFAULT_TIMEOUT = 5.0        # seconds a wait lasts before it raises
GONE_AFTER = 1.0             # seconds a claim waits for each sim's lease service (a dead one's registration stays)
_tokens = itertools.count(1)
_inherited_node = False      # this process was forked from one where rospy already ran


class RosEnvError(RuntimeError):
    """The ROS side of an env failed: no master, no simulator, a simulator held by another env, not in lockstep, or
    one that stopped answering. The message names the namespace and says what to do."""


def _after_fork_in_child() -> None:
    global _inherited_node
    _inherited_node = rospy.core.is_initialized()


os.register_at_fork(after_in_child=_after_fork_in_child)


def master_answers(timeout: float) -> str:
    """'' if the master of ROS_MASTER_URI answers within timeout seconds, else why not (one line)."""
    uri = os.environ.get('ROS_MASTER_URI', '')
    if not uri:
        return 'ROS_MASTER_URI is not set: source the workspace (source devel/setup.bash) or export it'
    parts = urllib.parse.urlparse(uri)
    try:
        with socket.create_connection((parts.hostname, parts.port or 11311), timeout=timeout):
            pass
    except OSError as e:
        return (f'no ROS master answers at {uri} ({e.strerror or e}) within {timeout:g} s: start roscore, or the '
                f'simulators\' launch file')
    return ''


def ensure_node(timeout: float = DEFAULT_TIMEOUT) -> None:
    """A rospy node in this process: the caller's own, or an anonymous one started here once the master answers."""
    if _inherited_node:
        raise RosEnvError('this process was forked from one where rospy already ran, and rospy\'s threads do not '
                          'survive a fork: make the envs in the worker processes only, or start them with '
                          'AsyncVectorEnv(..., context="spawn")')
    if rospy.core.is_initialized():
        return
    problem = master_answers(timeout)
    if problem:
        raise RosEnvError(problem)
    argv = sys.argv
    if multiprocessing.parent_process() is not None:
        # a spawned worker's argv is its parent's: a __name:= there (roslaunch's, rostest's) would register this
        # process under the parent node's name, and the master would shut the parent down
        argv = [a for a in argv if not a.startswith(('__name:=', '__log:='))]
    rospy.init_node('robot_ai_env', argv=argv, anonymous=True, disable_signals=True)


def new_token() -> str:
    """A lease token of this process's: its node name, its pid and a number (two envs of a process: two tokens)."""
    return f'{rospy.get_name()}#{os.getpid()}-{next(_tokens)}'


def resolve(ns: str, name: str) -> str:
    return rospy.resolve_name(f'{ns.rstrip("/")}/{name}' if ns else name)


def namespace_of(service: str, sim: str) -> str:
    """'/cartpole_3' of '/cartpole_3/cartpole_sim/lease' ('/' at the root)."""
    return service[:-len(f'/{sim}/lease')] or '/'


def running_sims(sim: str) -> list[str]:
    """The namespaces of every running sim of this kind (its ~lease service), in natural order (2 before 10)."""
    try:
        services = rospy.get_master().getSystemState()[2][2]
    except Exception as e:         # the master went away since the node started
        raise RosEnvError(f'the ROS master does not answer: {e}') from None
    found = [namespace_of(name, sim) for name, _ in services if name.endswith(f'/{sim}/lease')]
    return sorted(found, key=lambda ns: [int(t) if t.isdigit() else t for t in re.split(r'(\d+)', ns)])


def _call(ns: str, sim: str, token: str, release_it: bool, timeout: float, launch_hint: str = ''):
    from robot_ai.srv import Lease
    service = resolve(ns, f'{sim}/lease')
    try:
        rospy.wait_for_service(service, timeout)
    except rospy.ROSException:
        hint = f' (start the sims first: {launch_hint})' if launch_hint else ''
        raise RosEnvError(f'{ns}: no {sim}: its service {service} did not appear within {timeout:g} s{hint}') from None
    try:
        return rospy.ServiceProxy(service, Lease)(token=token, release=release_it)
    except (rospy.ServiceException, OSError) as e:
        raise RosEnvError(f'{ns}: {sim}\'s lease failed ({e}): the sim stopped or died') from None


def lease(ns: str, sim: str, token: str, timeout: float, launch_hint: str = '') -> None:
    """Take the lease of the sim in ns for token, or RosEnvError naming who holds it."""
    answer = _call(ns, sim, token, False, timeout, launch_hint)
    if not answer.success:
        raise RosEnvError(f'{ns}: {answer.message}: an env needs a sim of its own (start more sims, or close the '
                          f'other env)')


def release(ns: str, sim: str, token: str, timeout: float = 1.0) -> None:
    """Give the lease back (quietly: a sim that is gone holds nothing)."""
    try:
        _call(ns, sim, token, True, timeout)
    except RosEnvError:
        pass


def take(ns: str, sim: str, token: str, timeout: float, launch_hint: str, unusable=None, said: str = '') -> str:
    """The namespace of the sim an env leases for token: ns's (resolved), or RosEnvError naming its holder, or
    '<ns>: <said><the reason unusable(ns) gives>' (the lease given back); without ns, claim's."""
    if not ns:
        return claim(sim, token, timeout, launch_hint, unusable)
    ns = rospy.resolve_name(ns)
    lease(ns, sim, token, timeout, launch_hint)
    reason = unusable(ns) if unusable is not None else ''
    if reason:
        release(ns, sim, token)
        raise RosEnvError(f'{ns}: {said}{reason}')
    return ns


def claim(sim: str, token: str, timeout: float, launch_hint: str, unusable=None) -> str:
    """The namespace of the first running sim of this kind that token leases and that unusable(ns) has nothing
    against (a reason, or ''); RosEnvError naming every sim's holder or reason when none is left, or saying how to
    start some when none runs (waiting up to timeout for one)."""
    deadline = time.monotonic() + timeout
    while True:
        passed = []
        for ns in running_sims(sim):
            try:     # a sim killed without unregistering stays at the master: its service does not answer
                answer = _call(ns, sim, token, False, min(timeout, GONE_AFTER))
            except RosEnvError:
                passed.append(f'{ns} does not answer')
                continue
            if not answer.success:
                passed.append(f'{ns} leased to {answer.holder}')
                continue
            reason = unusable(ns) if unusable is not None else ''
            if not reason:
                return ns
            release(ns, sim, token)
            passed.append(f'{ns} {reason}')
        if passed:
            raise RosEnvError(f'no running {sim} is free for this env ({"; ".join(passed)}): start more sims '
                              f'({launch_hint}) or close the envs that hold them')
        if time.monotonic() > deadline:
            raise RosEnvError(f'no {sim} runs (none within {timeout:g} s): start them first ({launch_hint})')
        time.sleep(0.1)
