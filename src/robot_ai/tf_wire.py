"""ROS 1 wire format of sensor_msgs/JointState (read) and tf2_msgs/TFMessage (write), fast. No rospy.

genpy's generated (de)serialisers walk every field in Python; at 1 kHz that costs more CPU than the
kinematics. Here a JointState's names section is parsed once and then recognised by a byte comparison,
positions are read with numpy.frombuffer, and a TFMessage is written from a byte template cached per set
of joints, with stamps and transforms filled in by two numpy assignments.
"""
import struct

import genpy
import numpy as np

_U32 = struct.Struct('<I')
_HEADER = struct.Struct('<III')  # seq, stamp.secs, stamp.nsecs (then frame_id)
_STAMP = struct.Struct('<II')


class WireError(ValueError):
    """A buffer that is not a well-formed message."""


def raw_message_class(msg_class):
    """A message class with msg_class's type and md5sum whose instances carry their serialised bytes in
    ``buff``: rospy hands received bytes over untouched and publishes ``buff`` as it is."""

    class Raw(genpy.Message):
        _md5sum = msg_class._md5sum
        _type = msg_class._type
        _full_text = msg_class._full_text
        _has_header = False  # a header lives in the bytes; rospy must not try to set its seq
        __slots__ = ['buff']

        def __init__(self, buff=b''):
            self.buff = buff

        def serialize(self, buff):
            buff.write(self.buff)

        def deserialize(self, buff):
            self.buff = buff
            return self

    Raw.__name__ = 'Raw' + msg_class.__name__
    return Raw


class JointStateDecoder(object):
    """Reads header stamp, names and positions of serialised sensor_msgs/JointState messages."""

    def __init__(self):
        self._names_bytes = None
        self._names = ()

    def decode(self, buf):
        """Return (secs, nsecs, names tuple, positions float64 array) of one serialised JointState."""
        try:
            _, secs, nsecs = _HEADER.unpack_from(buf, 0)
            (frame_len,) = _U32.unpack_from(buf, 12)
            off = 16 + frame_len
            cached = self._names_bytes
            if cached is not None and buf.startswith(cached, off):
                names = self._names
                off += len(cached)
            else:
                start = off
                (count,) = _U32.unpack_from(buf, off)
                off += 4
                names = []
                for _ in range(count):
                    (n,) = _U32.unpack_from(buf, off)
                    off += 4
                    if off + n > len(buf):
                        raise WireError('a joint name runs past the end of the message')
                    names.append(buf[off:off + n].decode('utf-8', 'replace'))
                    off += n
                names = tuple(names)
                self._names_bytes, self._names = bytes(buf[start:off]), names
            (count,) = _U32.unpack_from(buf, off)
            positions = np.frombuffer(buf, '<f8', count, off + 4)
        except (struct.error, ValueError) as e:
            raise WireError('malformed JointState: %s' % e)
        return secs, nsecs, names, positions


class TFMessageEncoder(object):
    """Writes serialised tf2_msgs/TFMessage for subsets of a fixed list of (parent, child) frame pairs."""

    def __init__(self, parents, children):
        self._frames = [(_string(p), _string(c)) for p, c in zip(parents, children)]
        self._layouts = {}

    def _layout(self, idx):
        parts, stamp_at, data_at = [_U32.pack(len(idx))], [], []
        pos = 4
        for i in idx:
            parent, child = self._frames[i]
            parts.append(b'\0' * 12)          # seq (always 0, as tf2_ros), stamp secs, stamp nsecs
            stamp_at.append(pos + 4)
            pos += 12
            parts.append(parent)
            parts.append(child)
            pos += len(parent) + len(child)
            parts.append(b'\0' * 56)          # translation xyz, rotation xyzw: 7 float64
            data_at.append(pos)
            pos += 56
        template = np.frombuffer(b''.join(parts), np.uint8).copy()
        stamp_index = np.asarray(stamp_at, np.intp)[:, None] + np.arange(8)
        data_index = np.asarray(data_at, np.intp)[:, None] + np.arange(56)
        return template, stamp_index, data_index

    def encode(self, idx, secs, nsecs, xyz, quat):
        """Bytes of a TFMessage with transforms idx (indices into the frame list), all stamped secs.nsecs,
        translations xyz (K, 3) and rotations quat (K, 4, x y z w)."""
        data = np.empty((len(idx), 7))
        data[:, :3] = xyz
        data[:, 3:] = quat
        return self.encode_data(idx, secs, nsecs, data)

    def encode_data(self, idx, secs, nsecs, data):
        """As encode, with translation and rotation in one (K, 7) float64 array."""
        key = idx.tobytes() if isinstance(idx, np.ndarray) else tuple(idx)
        layout = self._layouts.get(key)
        if layout is None:
            if len(self._layouts) > 64:  # the set of joints a publisher sends rarely changes; stay bounded
                self._layouts.clear()
            layout = self._layouts[key] = self._layout([int(i) for i in idx])
        template, stamp_index, data_index = layout
        if len(idx):
            template[stamp_index] = np.frombuffer(_STAMP.pack(secs, nsecs), np.uint8)
            template[data_index] = np.ascontiguousarray(data, dtype='<f8').view(np.uint8)
        return template.tobytes()


def _string(s):
    raw = s.encode('utf-8')
    return _U32.pack(len(raw)) + raw
