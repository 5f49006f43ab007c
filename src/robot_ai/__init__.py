"""robot_ai: forward kinematics, the course's CartPole agents, the cart-pole robot and its gymnasium env."""
# catkin's devel space puts this folder first on sys.path; a process that inherits that sys.path (a worker started
# with multiprocessing's spawn) imports this file directly, and must still find the generated robot_ai.msg/.srv
from pkgutil import extend_path

__path__ = extend_path(__path__, __name__)
