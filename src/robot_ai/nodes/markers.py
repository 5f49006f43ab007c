"""rviz markers more than one node draws: the world's obstacles."""
from __future__ import annotations

import numpy as np
from visualization_msgs.msg import Marker, MarkerArray

OBSTACLE_COLOUR = (0.55, 0.45, 0.35, 0.8)


def quaternion(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix."""
    from tf import transformations as tft
    m = np.identity(4)
    m[:3, :3] = rotation
    return tuple(float(v) for v in tft.quaternion_from_matrix(m))


def obstacle_markers(obstacles, frame: str) -> MarkerArray:
    """The obstacles (motion.body's Obstacles) as markers in frame (namespace obstacles), to publish latched."""
    markers = MarkerArray()
    for k, o in enumerate(obstacles):
        m = Marker()
        m.header.frame_id = frame
        m.ns, m.id, m.action = 'obstacles', k, Marker.ADD
        m.type = Marker.CUBE if o.kind == 'box' else Marker.SPHERE
        size = o.size if o.kind == 'box' else (2 * o.size[0],) * 3
        m.scale.x, m.scale.y, m.scale.z = size
        m.pose.position.x, m.pose.position.y, m.pose.position.z = o.pose[:3, 3]
        x, y, z, w = quaternion(o.pose[:3, :3])
        m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w = x, y, z, w
        m.color.r, m.color.g, m.color.b, m.color.a = OBSTACLE_COLOUR
        markers.markers.append(m)
    return markers
