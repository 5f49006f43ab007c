"""Motion in joint space for any arm, below reach/: the arm's body and its world (motion.body: spheres fitted to the
URDF's collision geometry, a stated stand-in where a mesh is missing, the obstacles; batched checks), collision-free
paths (OMPL's RRT-Connect over a batched check) and their timing within the joint limits (TOPP-RA). No rospy, and
nothing of reach/: a body is built for any chain of joints (motion.body.Chain; reach.arm.Arm is one), a planner is
given the joint limits and a function that says which configurations are clear.

    body = CollisionModel(tree, urdf_text, arm, obstacles=parse_obstacles('world.yaml'))   # from motion.body
    planner = JointPlanner(lower, upper, clear=lambda q: ~body.in_collision(q, 0.02), sweep=sweep_per_radian)
    path = planner.plan(start, goals, time_limit=1.0)     # path.waypoints (k, n), or path.reason
    timed = time_path(path.waypoints, velocity, acceleration)  # timed.times, timed.positions, timed.velocities
"""
from robot_ai.motion.planner import JointPlanner, PlannedPath
from robot_ai.motion.timing import TimedPath, time_path

__all__ = ['JointPlanner', 'PlannedPath', 'TimedPath', 'time_path']
