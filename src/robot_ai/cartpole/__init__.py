"""Everything CartPole, with no rospy anywhere in this folder.

- ``dynamics``: gymnasium's CartPole constants and equations, batched and single-state; start states.
- ``linear_search``: the course's linear policy and its random search.
- ``q_learning``: the course's Q-learning agent with RBF features (its "TensorFlow warm-up").
- ``artifacts``: the output folder, file names, learning-curve plots and videos.

From the package's venv, with nothing sourced::

    python -m robot_ai.cartpole random-search --iterations 100 --episodes 100 --seed 0
    python -m robot_ai.cartpole q-learning --episodes 500 --seed 0 --learners 8
"""
