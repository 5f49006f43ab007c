"""robot_ai.tf_wire against genpy's generated (de)serialisers of the same message types."""
import io
import math

import numpy as np
import pytest
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from tf2_msgs.msg import TFMessage

from robot_ai.tf_wire import (JointStateDecoder, TFMessageEncoder, WireError, decode_float64_array,
                              encode_float64_array)


def serialise(msg):
    buff = io.BytesIO()
    msg.serialize(buff)
    return buff.getvalue()


def joint_state(names, positions, secs=12, nsecs=345, frame='base'):
    msg = JointState(name=list(names), position=list(positions))
    msg.header.stamp.secs, msg.header.stamp.nsecs, msg.header.frame_id = secs, nsecs, frame
    msg.velocity = [0.5] * len(names)
    return msg


def test_decode_matches_genpy_and_caches_names():
    dec = JointStateDecoder()
    names = ['a', 'joint_b', 'ü-unicode', '']
    for k in range(3):
        pos = [0.1 * k, -2.0, 1e300, 5.0]
        secs, nsecs, got_names, got_pos = dec.decode(serialise(joint_state(names, pos, secs=k, nsecs=7)))
        assert (secs, nsecs) == (k, 7)
        assert got_names == tuple(names)
        assert list(got_pos) == pos
    # a different set of names is parsed again, not taken from the cache
    _, _, got_names, got_pos = dec.decode(serialise(joint_state(['a', 'c'], [1.0, 2.0])))
    assert got_names == ('a', 'c') and list(got_pos) == [1.0, 2.0]


def test_decode_mismatched_lengths_and_empty():
    dec = JointStateDecoder()
    _, _, names, pos = dec.decode(serialise(joint_state(['a', 'b'], [1.0])))
    assert len(names) == 2 and len(pos) == 1
    _, _, names, pos = dec.decode(serialise(joint_state([], [])))
    assert names == () and len(pos) == 0


@pytest.mark.parametrize('cut', [3, 17, 30, 45])
def test_decode_truncated_raises(cut):
    buf = serialise(joint_state(['shoulder', 'elbow'], [1.0, 2.0]))
    with pytest.raises(WireError):
        JointStateDecoder().decode(buf[:cut])


def test_encode_matches_genpy_deserialisation():
    parents = ['base', 'l1', 'pre/l2', 'ü']
    children = ['l1', 'pre/l2', 'l3', 'x']
    enc = TFMessageEncoder(parents, children)
    rng = np.random.default_rng(0)
    for idx in ([0, 1, 2, 3], [2, 0], [], [3]):
        idx = np.array(idx, dtype=np.intp)
        xyz = rng.normal(size=(len(idx), 3))
        quat = rng.normal(size=(len(idx), 4))
        msg = TFMessage().deserialize(enc.encode(idx, 1795000000, 999999999, xyz, quat))
        assert len(msg.transforms) == len(idx)
        for k, t in enumerate(msg.transforms):
            assert t.header.frame_id == parents[idx[k]] and t.child_frame_id == children[idx[k]]
            assert (t.header.stamp.secs, t.header.stamp.nsecs) == (1795000000, 999999999)
            tr, r = t.transform.translation, t.transform.rotation
            assert [tr.x, tr.y, tr.z] == list(xyz[k]) and [r.x, r.y, r.z, r.w] == list(quat[k])
    # the cached layout is refilled, not reused stale
    idx = np.array([1], np.intp)
    a = TFMessage().deserialize(enc.encode(idx, 1, 2, np.zeros((1, 3)), np.array([[0, 0, 0, 1.0]])))
    b = TFMessage().deserialize(enc.encode(idx, 3, 4, np.ones((1, 3)), np.array([[0, 0, math.sin(1), math.cos(1)]])))
    assert a.transforms[0].header.stamp.secs == 1 and b.transforms[0].header.stamp.secs == 3
    assert b.transforms[0].transform.translation.x == 1.0


def test_raw_message_class_keeps_type_and_bytes():
    from robot_ai.tf_wire import raw_message_class
    raw = raw_message_class(JointState)
    assert (raw._type, raw._md5sum) == (JointState._type, JointState._md5sum)
    data = serialise(joint_state(['a'], [1.5]))
    msg = raw().deserialize(data)
    buff = io.BytesIO()
    msg.serialize(buff)
    assert buff.getvalue() == data


def test_joint_state_encoder_matches_genpy_with_and_without_efforts():
    """arm_sim writes joint_states itself: genpy reads them back, efforts empty unless given (the physics sim's)."""
    from robot_ai.tf_wire import JointStateEncoder
    encoder = JointStateEncoder(['a', 'joint_b'])
    for efforts in (None, np.array([1.5, -2.25])):
        msg = JointState().deserialize(encoder.encode(7, 12, 345, np.array([0.1, -0.2]), np.array([1.0, 2.0]),
                                                      efforts))
        assert (msg.header.stamp.secs, msg.header.stamp.nsecs, msg.name) == (12, 345, ['a', 'joint_b'])
        assert list(msg.position) == [0.1, -0.2] and list(msg.velocity) == [1.0, 2.0]
        assert list(msg.effort) == ([] if efforts is None else [1.5, -2.25])


def test_a_float64_array_is_written_as_rospy_writes_it_and_read_back():
    """encode_float64_array (the envs' commands) writes the bytes rospy's own serialiser writes for a
    std_msgs/Float64MultiArray with no layout, and decode_float64_array (arm_sim's reading) gives the values back."""
    for values in ([0.1, -2.5, 1e-300, float('inf'), 3.0], []):
        buffer = io.BytesIO()
        Float64MultiArray(data=values).serialize(buffer)
        assert encode_float64_array(values) == buffer.getvalue()
        assert decode_float64_array(encode_float64_array(values)).tolist() == values
