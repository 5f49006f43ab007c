"""joint_sweep: smooth, stamped joint_states for every movable, non-mimic joint, so frames move without a GUI.

Each joint follows a sinusoid inside its limits (continuous joints: +-1 rad), with its own phase, around the middle
of its limits or around ~home. An arm whose zero pose is stretched out at its base's height (a UR5) sweeps through
the floor around the middle of its limits: give it a ~home and a ~scale that keep it up (config/ur5_sweep.yaml).

ROS Parameters
    robot_description (str): the URDF, searched up the namespaces (waited for).
    ~rate (float, 50.0): messages per second.
    ~period (float, 8.0): seconds of one sweep.
    ~amplitude (float, 0.8): share of each joint's half range used.
    ~home (dict, {}): joint name -> the sweep's centre for that joint (rad or m), instead of the middle of its limits.
    ~scale (dict, {}): joint name -> a factor on that joint's amplitude.

ROS Publishers
    joint_states (sensor_msgs/JointState)
"""
import math

import rospy
from sensor_msgs.msg import JointState

from robot_ai.nodes.params import init_node, number_param, publish, quiet_on_shutdown
from robot_ai.nodes.robot_description import wait_for_tree


def sweep_ranges(tree, amplitude: float, home: dict | None = None, scale: dict | None = None) -> list[tuple]:
    """(name, centre, half-amplitude) of every active joint; home and scale override a joint's centre and scale its
    amplitude."""
    home, scale = home or {}, scale or {}
    out = []
    for name in tree.active_joints:
        j = tree.joints[name]
        if j.type == 'continuous' or j.lower is None or j.upper is None or j.upper <= j.lower:
            centre, half = 0.0, 1.0
        else:
            centre, half = (j.lower + j.upper) / 2.0, min((j.upper - j.lower) / 2.0, math.pi / 2)
        if j.type == 'prismatic':
            half = (j.upper - j.lower) / 2.0 if j.upper is not None and j.lower is not None else 0.05
        out.append((name, float(home.get(name, centre)), amplitude * half * float(scale.get(name, 1.0))))
    return out


def positions(ranges: list[tuple], t: float, period: float) -> list[float]:
    """Every joint's position at time t of the sweep: its own sinusoid, phase 0.9 rad apart from the previous one."""
    return [c + a * math.sin(2 * math.pi * t / period + 0.9 * i) for i, (_, c, a) in enumerate(ranges)]


def joint_map(name: str) -> dict:
    """A dict parameter of joint name -> number; anything else is ignored with a warning."""
    value = rospy.get_param(name, {})
    if isinstance(value, dict) and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                                       for v in value.values()):
        return value
    rospy.logwarn(f'{name} must map joint names to numbers, got {value!r}: ignored')
    return {}


@quiet_on_shutdown
def main():
    init_node('joint_sweep')
    rate = number_param('~rate', 50.0, 'a positive number (Hz)', lambda v: v > 0)
    period = number_param('~period', 8.0, 'a positive number (s)', lambda v: v > 0)
    amplitude = number_param('~amplitude', 0.8, 'a number from 0 to 1', lambda v: 0 <= v <= 1)
    tree, _ = wait_for_tree()
    if tree is None:
        return
    ranges = sweep_ranges(tree, amplitude, joint_map('~home'), joint_map('~scale'))
    rospy.loginfo(f'joint_sweep: {len(ranges)} joints at {rate:.0f} Hz')
    pub = rospy.Publisher('joint_states', JointState, queue_size=10)
    msg = JointState(name=[r[0] for r in ranges])
    t0 = rospy.Time.now()
    r = rospy.Rate(rate)
    while not rospy.is_shutdown():
        now = rospy.Time.now()
        t = (now - t0).to_sec()
        msg.header.stamp = now
        msg.position = positions(ranges, t, period)
        publish(pub, msg)            # a sweep in flight at Ctrl-C is dropped quietly
        try:
            r.sleep()
        except rospy.ROSInterruptException:
            break
