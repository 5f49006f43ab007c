"""ROS 1 wire format of sensor_msgs/JointState (read) and tf2_msgs/TFMessage (write and read), fast. No rospy.

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
_EMPTY_LAYOUT = struct.pack('<II', 0, 0)     # std_msgs/MultiArrayLayout with no dimension, data_offset 0


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


class JointStateEncoder:
    """Writes serialised sensor_msgs/JointState for a fixed list of joint names: positions and velocities (and
    efforts, where given), stamped; the names' bytes are written once."""

    def __init__(self, names):
        self.count = len(names)
        self._names = _U32.pack(len(names)) + b''.join(_string(n) for n in names)
        self._array = _U32.pack(len(names))

    def encode(self, seq: int, secs: int, nsecs: int, positions: np.ndarray, velocities: np.ndarray,
               efforts: np.ndarray | None = None) -> bytes:
        """Bytes of a JointState with an empty frame_id (and no efforts unless given). seq: the publisher's count of
        its messages (rospy writes it into the messages it serialises itself, not into these bytes)."""
        effort = _U32.pack(0) if efforts is None else self._array + np.ascontiguousarray(efforts, '<f8').tobytes()
        return b''.join((_HEADER.pack(seq, secs, nsecs), _U32.pack(0), self._names,
                         self._array, np.ascontiguousarray(positions, '<f8').tobytes(),
                         self._array, np.ascontiguousarray(velocities, '<f8').tobytes(), effort))


def encode_float64_array(values) -> bytes:
    """A serialised std_msgs/Float64MultiArray of values, with no layout (no dimension, data_offset 0): what
    decode_float64_array reads, as ros_control's group controllers take a command."""
    data = np.ascontiguousarray(values, '<f8')
    return _EMPTY_LAYOUT + _U32.pack(len(data)) + data.tobytes()


def decode_float64_array(buf) -> np.ndarray:
    """The data of a serialised std_msgs/Float64MultiArray (its layout skipped)."""
    try:
        (dims,) = _U32.unpack_from(buf, 0)
        off = 4
        for _ in range(dims):
            (n,) = _U32.unpack_from(buf, off)
            off += 4 + n + 8              # label, size, stride
        off += 4                          # data_offset
        (count,) = _U32.unpack_from(buf, off)
        if off + 4 + 8 * count > len(buf):
            raise WireError('the data runs past the end of the message')
        return np.frombuffer(buf, '<f8', count, off + 4)
    except struct.error as e:
        raise WireError(f'malformed Float64MultiArray: {e}')


def header_of(buf) -> tuple[int, int, int]:
    """(seq, stamp secs, stamp nsecs) of a serialised message that starts with a std_msgs/Header."""
    try:
        return _HEADER.unpack_from(buf, 0)
    except struct.error as e:
        raise WireError(f'malformed header: {e}')


_TRANSFORM = struct.Struct('<7d')


def decode_tf(buf) -> list[tuple[int, int, str, str, tuple]]:
    """The transforms of a serialised tf2_msgs/TFMessage: (stamp secs, stamp nsecs, parent frame, child frame,
    (x, y, z, qx, qy, qz, qw)) each."""
    out = []
    try:
        (count,) = _U32.unpack_from(buf, 0)
        off = 4
        for _ in range(count):
            _, secs, nsecs = _HEADER.unpack_from(buf, off)
            off += 12
            frames = []
            for _ in range(2):
                (n,) = _U32.unpack_from(buf, off)
                off += 4
                if off + n > len(buf):
                    raise WireError('a frame name runs past the end of the message')
                frames.append(bytes(buf[off:off + n]).decode('utf-8', 'replace'))
                off += n
            out.append((secs, nsecs, frames[0], frames[1], _TRANSFORM.unpack_from(buf, off)))
            off += 56
    except struct.error as e:
        raise WireError(f'malformed TFMessage: {e}')
    return out


class TFDecoder:
    """decode_tf for a stream of messages that carry the same frames in the same order (a forward_kinematics node's):
    the layout of the first is kept, and a next message of the same length whose frame names sit at the same places
    is read by offsets; any other message is parsed in full."""

    def __init__(self):
        self._length = -1
        self._names: list[tuple[int, bytes]] = []      # (offset, the name's bytes with their length) to compare
        self._items: list[tuple[int, int, str, str]] = []   # (stamp offset, data offset, parent, child)

    def decode(self, buf) -> list[tuple[int, int, str, str, tuple]]:
        view = memoryview(buf)
        if len(buf) == self._length and all(view[off:off + len(raw)] == raw for off, raw in self._names):
            out = []
            for stamp_at, data_at, parent, child in self._items:
                secs, nsecs = _STAMP.unpack_from(buf, stamp_at)
                out.append((secs, nsecs, parent, child, _TRANSFORM.unpack_from(buf, data_at)))
            return out
        out = decode_tf(buf)
        names, items, off = [], [], 4
        for secs, nsecs, parent, child, _ in out:
            stamp_at = off + 4
            off += 12
            for name in (parent, child):
                raw = _string(name)
                names.append((off, raw))
                off += len(raw)
            items.append((stamp_at, off, parent, child))
            off += 56
        self._length, self._names, self._items = len(buf), names, items
        return out


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
