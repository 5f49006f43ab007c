#!/usr/bin/env python3
"""Run RosCartPoleVectorEnv over the sims /cartpole_0 ... beside gymnasium's SyncVectorEnv under the same random
actions; print 'same as gymnasium: True|False' and a digest of every number the ROS env returned, so that runs on
different hosts can be compared. Used by test_across_machines.py.

    ros_env_digest.py NUM_ENVS STEPS SEED
"""
import hashlib
import sys

import gymnasium
import numpy as np


def main() -> int:
    n, steps, seed = (int(v) for v in sys.argv[1:4])
    ros = gymnasium.make_vec('robot_ai.envs:robot_ai/RosCartPole-v1', num_envs=n, timeout=20.0)
    ref = gymnasium.make_vec('CartPole-v1', num_envs=n, vectorization_mode='sync')
    rng = np.random.default_rng(seed)
    digest = hashlib.sha256()
    o1, o2 = ros.reset(seed=seed)[0], ref.reset(seed=seed)[0]
    same = bool((o1 == o2).all())
    digest.update(o1.tobytes())
    for _ in range(steps):
        a = rng.integers(2, size=n)
        r1, r2 = ros.step(a), ref.step(a)
        for x, y in zip(r1[:4], r2[:4]):
            same = same and x.dtype == y.dtype and bool((x == y).all())
            digest.update(np.ascontiguousarray(x).tobytes())
    ros.close()
    print(f'same as gymnasium: {same}')
    print(f'digest: {digest.hexdigest()}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
