"""robot_ai.grading.pacing in virtual time: check_fk's loop against simulated candidates that read joint_states from a
queue, as rospy does, and answer them one by one. A correct node's answer to each configuration is its own, however
slow it is, whether it drops messages or publishes on a timer; a node that ignores the joints or goes silent is
told apart from a slow one (issue 56: a correct node sleeping 0.4 s was failed on a wrong joint)."""
import collections

import numpy as np
import pytest

from robot_ai.grading.pacing import Pacer

TICK = 0.01      # check_fk's loop sleeps this long between looks


def poses_of(value: float) -> dict:
    m = np.eye(4)
    m[:3, 3] = value
    return {'link': m}


class Node:
    """A candidate: joint_states queued (unbounded, rospy's default), each read after `delay` seconds of work and
    answered with its poses in one message; every_other: every second message is dropped; timer: the latest state
    read is published every `timer` seconds instead; ignores: the poses never move; quits_after: no answer after
    that many configurations' messages."""

    def __init__(self, delay=0.0, every_other=False, timer=0.0, ignores=False, quits_at=None, wrong=1.0, burst=1):
        self.delay, self.every_other, self.timer = delay, every_other, timer
        self.ignores, self.quits_at = ignores, quits_at
        self.wrong, self.burst = wrong, burst     # its poses: wrong x the joint value; messages per answer
        self.queue, self.busy_until, self.working, self.read, self.state, self.next_tick = \
            collections.deque(), 0.0, None, 0, None, 0.0

    def receive(self, value):
        self.queue.append(value)

    def step(self, now) -> list:
        out = []
        if self.working is not None and now >= self.busy_until:
            self.state, self.working = self.working, None
            if not self.timer:
                out.extend([self.state] * self.burst)
        if self.working is None and self.queue:
            value = self.queue.popleft()
            self.read += 1
            if self.every_other and self.read % 2:
                return out
            if self.quits_at is not None and value >= self.quits_at:
                return out
            self.working, self.busy_until = (0.0 if self.ignores else self.wrong * value), now + self.delay
        if self.timer and self.state is not None and now >= self.next_tick:
            self.next_tick = now + self.timer
            out.append(self.state)
        return out


def grade(node: Node, configurations: int = 12, timeout: float = 5.0):
    """check_fk's settle loop over configurations 1, 2, ...: [(value answered, why, virtual seconds)], the pacer."""
    pacer, now, previous, out = Pacer(timeout), 0.0, None, []
    for k in range(1, configurations + 1):
        pacer.begin(now, previous, True)
        t0 = now
        while pacer.answer is None:
            if pacer.want_send(now):
                node.receive(float(k))
                pacer.sent_at(now)
            now += TICK
            for value in node.step(now):
                pacer.message(now, poses_of(value))
            pacer.tick(now)
            assert now - t0 < 60, f'configuration {k} never answered'
        answer = pacer.answer
        previous = answer.poses
        out.append((float(answer.poses['link'][0, 3]) if answer.poses else None, answer.why, now - t0))
        if answer.why == 'silent':
            break
    return out, pacer


@pytest.mark.parametrize('delay', [0.0, 0.1, 0.4, 1.0, 2.0])
def test_a_correct_node_is_graded_on_its_own_answer_however_slow(delay):
    out, pacer = grade(Node(delay=delay))
    assert [v for v, _, _ in out] == [float(k) for k in range(1, 13)], out
    assert {why for _, why, _ in out} == {'settled'}
    # one send in flight once the node's pace is known: two whole answers a configuration, not a backlog of old ones
    # (the sends made before, while the first configuration waited, are answered during the second)
    assert max(s for _, _, s in out[2:]) <= 2 * delay + 0.5, out
    assert not pacer.unanswered()


@pytest.mark.parametrize('delay', [0.0, 0.4, 1.0])
def test_a_wrong_node_is_graded_on_its_own_answer_however_slow(delay):
    out, _ = grade(Node(delay=delay, wrong=-2.0, burst=7))
    assert [v for v, _, _ in out] == [-2.0 * k for k in range(1, 13)], out


def test_a_node_that_answers_every_other_message():
    out, _ = grade(Node(delay=0.05, every_other=True))
    assert [v for v, _, _ in out] == [float(k) for k in range(1, 13)], out


@pytest.mark.parametrize('delay', [0.0, 0.4])
def test_a_node_that_publishes_on_a_timer_what_its_slow_callback_read(delay):
    out, _ = grade(Node(delay=delay, timer=0.02))
    assert [v for v, _, _ in out] == [float(k) for k in range(1, 13)], out


def test_a_node_that_ignores_the_joints_is_graded_on_what_it_gives_within_seconds():
    out, pacer = grade(Node(ignores=True))
    assert [v for v, _, _ in out] == [0.0] * 12
    assert all(s < 3.0 for _, _, s in out), out
    assert not pacer.reacted


def test_a_node_that_stops_answering_is_too_slow_not_wrong():
    out, pacer = grade(Node(delay=0.1, quits_at=5), timeout=3.0)
    assert [v for v, _, _ in out[:4]] == [1.0, 2.0, 3.0, 4.0]
    assert out[-1][1] == 'silent' and len(out) == 5
    assert pacer.unanswered()           # configuration 5 showed only 4's poses: no wrong joint to blame
