"""When check_fk sends a configuration to the candidate (again), and which of the candidate's poses are its answer to
it. No rospy: the grader's loop (``nodes/check_fk.py``) feeds it the clock and the candidate's messages.

    pacer = Pacer(timeout=5.0)                      # one per check: it learns how slow the candidate is
    pacer.begin(time.monotonic(), previous, changes)
    while (answer := pacer.answer) is None:
        now = time.monotonic()
        if pacer.want_send(now):
            send(q); pacer.sent_at(now)
        if a_fresh_tf_message_came:
            pacer.message(now, poses_now())
        pacer.tick(now)
    answer.poses, answer.why                        # 'settled', 'same as before', 'silent', 'unsettled'

A slow node queues the joint_states it has not read yet, and answers them one by one: a send it has not answered
is one more old answer to come. So a send goes out only once every send before it is answered (an answer: a burst of
fresh messages, then QUIET seconds without one), or when the candidate has been idle for `patience` seconds with
sends outstanding (taken as lost: twice the longest the candidate took lately to answer, at least RESEND, doubling while
none comes). A node that sleeps a second per message is sent one message a second, not five, and a backlog made
before its pace was known drains.

Poses count once they stayed the same over STABLE fresh messages, or over two whole answers. Poses that equal one
of the last answers (the previous configurations') while the reference moved are an old answer still coming; they
count only after SAME_AS_BEFORE messages and three times the longest the candidate ever took to show a new
configuration (a node that ignores the joints is wrong, and is graded so).
"""
from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field

import numpy as np

RESEND = 0.2            # seconds without an answer after which a send is made again, at first (then learned)
QUIET = 0.03            # seconds without a tf message that end an answer (a node that publishes a message per link
                        # answers one send with a burst, which must not bring a send per message)
STABLE = 3              # fresh messages in a row with the same poses: the candidate's answer
STABLE_ANSWERS = 2      # or whole answers in a row with the same poses
SAME_AS_BEFORE = 15     # fresh messages with an earlier configuration's poses before they may count as the answer
STALE_WAIT = 1.0        # seconds, and three times the longest a new configuration took to show, before they count
MAX_MESSAGES = 400      # fresh messages for one configuration whose poses never settle: the last ones count
HISTORY = 3             # earlier answers an old answer still coming is recognised by
LATENCIES = 5           # answer times the patience is learned from


def same(a: dict, b: dict, tolerance: float = 1e-9) -> bool:
    """Whether two {link: 4x4} poses are the same links at the same poses."""
    return a.keys() == b.keys() and all(np.allclose(a[k], b[k], atol=tolerance, rtol=0) for k in a)


@dataclass
class Answer:
    poses: dict           # {link: 4x4} of the graded links the candidate gave
    why: str              # settled | same as before | silent (no message for the timeout) | unsettled (MAX_MESSAGES)


@dataclass
class Pacer:
    """The sends and answers of one check, across its configurations (see the module's docstring)."""
    timeout: float                       # seconds without any fresh message after which a configuration is given up
    outstanding: int = 0                 # sends not answered yet (those taken as lost included: a slow node's queue)
    patience: float = RESEND
    last_send: float = -math.inf
    heard: float = -math.inf             # the last fresh message
    answer_ended: float = -math.inf      # when the last answer ended
    in_answer: bool = False              # fresh messages came and QUIET has not passed since
    clean_send: float | None = None      # a send made with nothing outstanding, until its first message
    latencies: collections.deque = field(default_factory=lambda: collections.deque(maxlen=LATENCIES))
    change_latency: float = 0.0          # the longest a configuration's new poses took to show after its first send
    reacted: bool = False                # some configuration's answer differed from the one before: it reads joints
    earlier: collections.deque = field(default_factory=lambda: collections.deque(maxlen=HISTORY))
    answer: Answer | None = None

    def begin(self, now: float, previous: dict | None, changes: bool) -> None:
        """A new configuration; previous: the candidate's answer to the one before (None for the first); changes:
        whether the reference poses differ from the previous configuration's."""
        if previous is not None:
            self.earlier.appendleft(previous)
        self.previous, self.changes = previous, changes
        self.begun, self.first_send, self.shown = now, None, False
        self.last, self.stable, self.answers_same, self.answer_poses = {}, 0, 0, None
        self.same_as_before, self.messages, self.answer = 0, 0, None

    def want_send(self, now: float) -> bool:
        """Whether to send the configuration now: every send answered and the last answer over, or the candidate
        idle for `patience` seconds with sends outstanding (taken as lost)."""
        self.tick(now)
        if self.answer is not None:
            return False
        if self.first_send is None:        # a new configuration goes out at once (a node that publishes on a
            return True                    # timer never goes quiet)
        if self.outstanding == 0 and not self.in_answer:
            return True
        if self.outstanding > 0 and now - max(self.last_send, self.heard) >= self.patience:
            # lost (a node that drops messages), or slower than we knew: once more, and later next time. Once its
            # pace is known, a candidate idle that long has nothing queued: what is outstanding was dropped
            if self.latencies:
                self.outstanding = 0
            self.patience = min(2 * self.patience, max(RESEND, self.timeout))
            return True
        return False

    def sent_at(self, now: float) -> None:
        if self.outstanding == 0:
            self.clean_send = now
        self.outstanding += 1
        self.last_send = now
        if self.first_send is None:
            self.first_send = now

    def message(self, now: float, poses: dict) -> None:
        """A fresh tf message came; poses: the graded links' poses now."""
        if not self.in_answer:                   # an answer begins: how long the candidate took to it
            if self.clean_send is not None:      # a send made with nothing outstanding
                self.latencies.append(now - self.clean_send)
            elif self.outstanding > 0 and self.last_send < self.answer_ended:   # the next of its queue, unasked
                self.latencies.append(now - self.answer_ended)
            self.clean_send = None
        self.heard, self.in_answer = now, True
        self.messages += 1
        if not poses or not same(poses, self.last):
            self.last, self.stable = poses, 1
            if (not self.shown and poses and self.previous is not None and self.changes
                    and self.first_send is not None and not self.stale(poses)):
                self.shown = True           # the configuration shows: how long that took
                self.change_latency = max(self.change_latency, now - self.first_send)
        else:
            self.stable += 1
        if self.messages >= MAX_MESSAGES:
            self.answer = Answer(self.last, 'unsettled')
        elif self.stable >= STABLE:
            self._consider(now)

    def tick(self, now: float) -> None:
        """The clock: the end of an answer (QUIET seconds after its last message), or of the wait (the timeout)."""
        if self.answer is not None:
            return
        if self.in_answer and now - self.heard >= QUIET:
            self.in_answer, self.answer_ended = False, self.heard
            self.outstanding = max(0, self.outstanding - 1)
            if self.latencies:
                self.patience = max(RESEND, 2 * max(self.latencies))
            if self.answer_poses is not None and self.last and same(self.last, self.answer_poses):
                self.answers_same += 1
            else:
                self.answers_same = 1
            self.answer_poses = self.last
            if self.answers_same >= STABLE_ANSWERS:
                self._consider(now)
        elif now - max(self.heard, self.begun) > self.timeout:
            self.answer = Answer(self.last, 'silent')

    def stale(self, poses: dict) -> bool:
        """Whether poses are an earlier configuration's answer while the reference moved: an old answer still
        coming."""
        return self.changes and any(same(poses, e) for e in self.earlier)

    def _consider(self, now: float) -> None:
        poses = self.last
        if not self.stale(poses):
            if self.previous is not None and self.changes:
                self.reacted = True
            self.answer = Answer(poses, 'settled')
            return
        self.same_as_before += 1
        waited = now - (self.first_send if self.first_send is not None else self.begun)
        if self.same_as_before >= SAME_AS_BEFORE and waited >= max(STALE_WAIT, 3 * self.change_latency):
            self.answer = Answer(poses, 'same as before')

    def unanswered(self) -> bool:
        """Whether the candidate, which does read the joints, gave no answer of its own to this configuration: it
        went silent before any, or showing an earlier one."""
        return (self.answer is not None and self.answer.why == 'silent' and self.reacted
                and (self.messages == 0 or self.stale(self.answer.poses)))
