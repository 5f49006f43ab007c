"""Everything CartPole, with no rospy anywhere in this folder.

- ``dynamics``: gymnasium's CartPole constants and equations, batched and single-state; start states.
- ``linear_search``: the course's linear policy and its random search.
- ``q_learning``: the course's Q-learning agent with RBF features (its "TensorFlow warm-up").
- ``policy_kinds``: its policy files (kinds linear and q_learning), its envs as policies see them, the loader.
- ``outputs``: what its runs leave behind: learning-curve plot jobs, CSV logs, videos (robot_ai.artifacts writes them).

From the package's venv, with nothing sourced::

    python -m robot_ai.cartpole random-search --iterations 100 --episodes 100 --seed 0
    python -m robot_ai.cartpole q-learning --episodes 500 --seed 0 --learners 8
"""
# registers the linear and q_learning kinds and the CartPoles as envs a policy acts in
from robot_ai.cartpole import policy_kinds  # noqa: E402,F401
