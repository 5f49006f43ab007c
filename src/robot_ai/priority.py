"""A node's threads at a higher scheduling priority, where the machine allows it. No rospy.

    note = raise_priority(-10)      # every thread of this process, and those they start from now on

A real arm's trajectory controller runs in a real-time loop. arm_sim stands in for one, and reach_controller's
trajectories must reach it within the safety layer's lead (two control periods, robot_ai.reach.safety): one that
comes later is spliced in from where the arm is, with a jolt, as a joint_trajectory_controller splices it. On a
loaded machine (rostests side by side) a trajectory came 47 to 152 ms after its start, three times in a run, with
both nodes at the default priority. At nice -10 the kernel runs them soon after they wake, ahead of busy processes
at nice 0; both sleep between steps, so they take no more of the processor than before.

Linux keeps a nice value per thread (a new thread takes its creator's), so every thread of /proc/self/task is set.
Raising a priority needs root or CAP_SYS_NICE: without them nothing changes and the note says so.
"""
from __future__ import annotations

import os

NICE = -10        # nice value the nodes ask for (-20 .. 19; lower runs sooner)


def raise_priority(nice: int = NICE) -> str:
    """Every thread of this process at nice value `nice` where it is now higher (lower is left alone); a line saying
    what was done or why not. 0 or more: nothing is done."""
    if not -20 <= nice <= 19:
        raise ValueError(f'a nice value is from -20 to 19, got {nice}')
    try:
        threads = sorted(int(t) for t in os.listdir('/proc/self/task'))
    except OSError:                 # no /proc: this thread only
        threads = [0]
    now = os.getpriority(os.PRIO_PROCESS, 0)
    if nice >= now:
        return f'at its own priority (nice {now})'
    for tid in threads:
        try:
            if os.getpriority(os.PRIO_PROCESS, tid) > nice:
                os.setpriority(os.PRIO_PROCESS, tid, nice)
        except ProcessLookupError:  # a thread that ended meanwhile
            continue
        except PermissionError:
            return (f'at its own priority (nice {now}): nice {nice}, which a loaded machine delays less, needs root or '
                    f'CAP_SYS_NICE')
    return f'at nice {nice} (from {now}), so that a loaded machine delays it less'
