#!/usr/bin/env python3
"""Load benchmark: robot_state_publisher (Debian, C++) and forward_kinematics (this package) on one stream.

For each robot, both nodes run on their own master-less namespace of one private master, subscribe to the
same joint_states topic and publish on their own tf topic. A feeder sends JointStates with distinct stamps
(stamp = send time) at a fixed rate; publish_frequency is high enough that neither node throttles.
Printed per node: share of inputs answered, CPU seconds per 1000 messages (utime + stime from /proc),
p50/p99 latency (receive time minus stamp), and the cost of message (de)serialisation measured apart.

    python bench/fk_load.py [--seconds 10]
"""
import argparse
import io
import os
import signal
import socket
import struct
import subprocess
import threading
import time

import numpy as np

HERE = os.path.dirname(os.path.realpath(__file__))
ROBOTS = os.path.join(HERE, '..', '..', 'shared', 'robots')
CASES = [('KUKA LWR', 'kuka_lwr_arm.urdf', 1000.0), ('PR2', 'pr2.urdf', 200.0)]
CLK_TCK = os.sysconf('SC_CLK_TCK')


def cpu_seconds(pid):
    with open('/proc/%d/stat' % pid) as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / float(CLK_TCK)


def free_port():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def serialisation_costs(pr2_xml):
    """Microseconds per PR2-sized message: genpy vs robot_ai.tf_wire, both directions."""
    from sensor_msgs.msg import JointState
    from tf2_msgs.msg import TFMessage
    from geometry_msgs.msg import TransformStamped
    from robot_ai.kinematics import KinematicTree
    from robot_ai.tf_wire import JointStateDecoder, TFMessageEncoder
    tree = KinematicTree.from_xml_string(pr2_xml)
    plan = tree.transform_plan()
    names = tree.active_joints
    js = JointState(name=names, position=[0.1] * len(names))
    buf = io.BytesIO()
    js.serialize(buf)
    raw = buf.getvalue()
    n = 2000
    t = time.perf_counter()
    for _ in range(n):
        JointState().deserialize(raw)
    genpy_in = (time.perf_counter() - t) / n * 1e6
    dec = JointStateDecoder()
    t = time.perf_counter()
    for _ in range(n):
        dec.decode(raw)
    ours_in = (time.perf_counter() - t) / n * 1e6
    k = len(plan.names)
    msg = TFMessage(transforms=[TransformStamped() for _ in range(k)])
    for i, tr in enumerate(msg.transforms):
        tr.header.frame_id, tr.child_frame_id = plan.parent_frames[i], plan.child_frames[i]
    t = time.perf_counter()
    for _ in range(n):
        b = io.BytesIO()
        msg.serialize(b)
    genpy_out = (time.perf_counter() - t) / n * 1e6
    enc = TFMessageEncoder(plan.parent_frames, plan.child_frames)
    idx = np.arange(k)
    xyz, quat = np.zeros((k, 3)), np.tile([0, 0, 0, 1.0], (k, 1))
    t = time.perf_counter()
    for _ in range(n):
        enc.encode(idx, 1, 2, xyz, quat)
    ours_out = (time.perf_counter() - t) / n * 1e6
    layout = plan.message_layout(tuple(names))
    positions = np.full(len(names), 0.1)
    t = time.perf_counter()
    for _ in range(n):
        plan.message_transforms(layout, positions)
    fk = (time.perf_counter() - t) / n * 1e6
    return dict(joints=len(names), transforms=k, genpy_in=genpy_in, ours_in=ours_in, genpy_out=genpy_out,
                ours_out=ours_out, fk=fk)


def run_case(label, urdf, rate, seconds, warmup=2.0):
    import rospy
    from sensor_msgs.msg import JointState
    from tf2_msgs.msg import TFMessage
    with open(os.path.join(ROBOTS, urdf)) as f:
        xml = f.read()
    ns = '/bench_%s' % urdf.split('.')[0]
    rospy.set_param(ns + '/robot_description', xml)
    procs = {}
    cmds = {'robot_state_publisher': ['/usr/lib/robot_state_publisher/robot_state_publisher'],
            'forward_kinematics': ['rosrun', 'robot_ai', 'forward_kinematics']}
    for who, cmd in cmds.items():
        procs[who] = subprocess.Popen(cmd + ['__ns:=' + ns, '__name:=' + who, '_publish_frequency:=5000.0',
                                             '/tf:=%s/%s/tf' % (ns, who), '/tf_static:=%s/%s/tf_static' % (ns, who)],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=os.setsid)
    from robot_ai.tf_wire import raw_message_class
    RawJS, RawTF = raw_message_class(JointState), raw_message_class(TFMessage)
    received = {who: [] for who in procs}
    counting = threading.Event()

    def on_tf(who):
        def cb(msg):
            now = time.time()
            if counting.is_set():
                secs, nsecs = struct.unpack_from('<II', msg.buff, 8)  # first transform's header stamp
                received[who].append((secs + nsecs * 1e-9, now))
        return cb
    subs = [rospy.Subscriber('%s/%s/tf' % (ns, who), RawTF, on_tf(who), queue_size=10000, tcp_nodelay=True)
            for who in procs]
    pub = rospy.Publisher(ns + '/joint_states', RawJS, queue_size=10, tcp_nodelay=True)
    deadline = time.time() + 30
    while (pub.get_num_connections() < 2 or any(s.get_num_connections() < 1 for s in subs)) and time.time() < deadline:
        time.sleep(0.05)
    # one serialised JointState; only the stamp changes between messages
    from robot_ai.kinematics import KinematicTree
    names = KinematicTree.from_xml_string(xml).active_joints
    js = JointState(name=names, position=list(np.linspace(-0.5, 0.5, len(names))))
    b = io.BytesIO()
    js.serialize(b)
    template = bytearray(b.getvalue())
    period = 1.0 / rate

    def feed(duration, count=False):
        sent, t_next = [], time.time()
        end = t_next + duration
        while True:
            now = time.time()
            if now >= end:
                return sent
            if now < t_next:
                time.sleep(min(t_next - now, 0.0005))
                continue
            t_next += period
            secs, nsecs = int(now), int((now % 1) * 1e9)
            struct.pack_into('<II', template, 4, secs, nsecs)
            pub.publish(RawJS(bytes(template)))
            if count:
                sent.append(secs + nsecs * 1e-9)
    feed(warmup)
    time.sleep(0.2)
    cpu0 = {who: cpu_seconds(p.pid) for who, p in procs.items()}
    counting.set()
    sent = feed(seconds, count=True)
    time.sleep(0.5)
    counting.clear()
    cpu1 = {who: cpu_seconds(p.pid) for who, p in procs.items()}
    rows = {}
    sent_set = set(round(s, 6) for s in sent)
    for who in procs:
        stamps = {round(s, 6) for s, _ in received[who]} & sent_set
        lat = np.array([(r - s) * 1e3 for s, r in received[who]])
        cpu = cpu1[who] - cpu0[who]
        rows[who] = dict(answered=len(stamps) / float(len(sent)), cpu_ms=cpu / len(sent) * 1e3,
                         p50=np.percentile(lat, 50) if len(lat) else float('nan'),
                         p99=np.percentile(lat, 99) if len(lat) else float('nan'))
    for s in subs:
        s.unregister()
    pub.unregister()
    for p in procs.values():
        os.killpg(p.pid, signal.SIGINT)
    for p in procs.values():
        p.wait(10)
    return len(sent) / seconds, rows


def rss_mib(pid):
    with open('/proc/%d/status' % pid) as f:
        return next(int(l.split()[1]) for l in f if l.startswith('VmRSS')) / 1024.0


def name_flood(seconds=20.0, rate=1000.0):
    """forward_kinematics fed JointStates whose 20 names are new every time (plus one real joint): its resident
    memory at the start, after half the flood and at the end (issue 12: it grew from 89 to 957 MB in 60 s)."""
    import rospy
    from sensor_msgs.msg import JointState
    with open(os.path.join(ROBOTS, 'kuka_lwr_arm.urdf')) as f:
        rospy.set_param('/bench_flood/robot_description', f.read())
    proc = subprocess.Popen(['rosrun', 'robot_ai', 'forward_kinematics', '__ns:=/bench_flood', '__name:=fk',
                             '/tf:=/bench_flood/tf', '/tf_static:=/bench_flood/tf_static', '_ignore_timestamp:=true'],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=os.setsid)
    pub = rospy.Publisher('/bench_flood/joint_states', JointState, queue_size=100)
    try:
        deadline = time.time() + 30
        while pub.get_num_connections() < 1 and time.time() < deadline:
            time.sleep(0.05)
        time.sleep(1.0)
        samples, n, t0 = [rss_mib(proc.pid)], 0, time.time()
        while time.time() - t0 < seconds:
            names = ['flood_%d_%d' % (n, i) for i in range(20)] + ['lwr_arm_0_joint']
            pub.publish(JointState(name=names, position=[0.0] * 21))
            n += 1
            if n == int(rate * seconds / 2):
                samples.append(rss_mib(proc.pid))
            time.sleep(1.0 / rate)
        time.sleep(1.0)
        samples.append(rss_mib(proc.pid))
        return n, time.time() - t0, samples
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(10)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--seconds', type=float, default=10.0)
    args = ap.parse_args()
    port = free_port()
    os.environ['ROS_MASTER_URI'] = 'http://127.0.0.1:%d' % port
    master = subprocess.Popen(['rosmaster', '--core', '-p', str(port)], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, preexec_fn=os.setsid)
    try:
        import rospy
        time.sleep(1.0)
        rospy.init_node('bench_fk_load', disable_signals=True)
        print('forward_kinematics vs robot_state_publisher, %g s per robot, %d cores' % (args.seconds, os.cpu_count()))
        print('%-9s %-22s %8s %9s %12s %9s %9s' % ('robot', 'node', 'rate', 'answered', 'CPU ms/msg',
                                                   'p50 ms', 'p99 ms'))
        ratios = []
        for label, urdf, rate in CASES:
            achieved, rows = run_case(label, urdf, rate, args.seconds)
            for who, r in rows.items():
                print('%-9s %-22s %6.0f Hz %8.1f%% %12.3f %9.2f %9.2f' % (
                    label, who, achieved, 100 * r['answered'], r['cpu_ms'], r['p50'], r['p99']))
            ratio = rows['forward_kinematics']['cpu_ms'] / rows['robot_state_publisher']['cpu_ms']
            ratios.append(ratio)
            print('%-9s CPU ratio forward_kinematics / robot_state_publisher = %.2f' % (label, ratio))
        with open(os.path.join(ROBOTS, 'pr2.urdf')) as f:
            c = serialisation_costs(f.read())
        print('\nper PR2 message (%d joints in, %d transforms out), microseconds:' % (c['joints'], c['transforms']))
        print('  JointState deserialise: genpy %.1f, robot_ai.tf_wire %.1f' % (c['genpy_in'], c['ours_in']))
        print('  TFMessage serialise:    genpy %.1f, robot_ai.tf_wire %.1f' % (c['genpy_out'], c['ours_out']))
        print('  kinematics (TransformPlan.message_transforms, the node\'s path): %.1f' % c['fk'])
        n, took, rss = name_flood()
        print('\nflood of ever-new joint names (%d JointStates of 21 names in %.0f s): forward_kinematics resident '
              'memory %.0f MiB at the start, %.0f halfway, %.0f at the end' % (n, took, rss[0], rss[1], rss[-1]))
    finally:
        os.killpg(master.pid, signal.SIGINT)
        master.wait(10)


if __name__ == '__main__':
    main()
