from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

setup(**generate_distutils_setup(packages=['robot_ai', 'robot_ai.cartpole', 'robot_ai.envs', 'robot_ai.nodes',
                                           'robot_ai.reach'],
                                 package_dir={'': 'src'}))
