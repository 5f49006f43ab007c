from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

# every package under src/robot_ai (test_layers.py holds this list to the folders): an install space without one of
# them imports nothing of it
setup(**generate_distutils_setup(packages=['robot_ai', 'robot_ai.cartpole', 'robot_ai.envs', 'robot_ai.grading',
                                           'robot_ai.motion', 'robot_ai.nodes', 'robot_ai.physics',
                                           'robot_ai.policies', 'robot_ai.reach'],
                                 package_dir={'': 'src'}))
