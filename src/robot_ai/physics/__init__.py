"""Physics under the arms: MuJoCo models built from the package's own robot model (physics.model). Beside reach/,
above it: the manipulation envs will live here. No rospy."""
from robot_ai.physics.model import Physics, PhysicsError, build_physics, parse_objects

__all__ = ['Physics', 'PhysicsError', 'build_physics', 'parse_objects']
