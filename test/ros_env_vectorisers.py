#!/usr/bin/env python3
"""One of gymnasium's standard vectorisers over robot_ai/RosCartPole-v1, in a process of its own (as a user's
training script is), beside gymnasium's SyncVectorEnv over CartPole-v1 under the same random actions; prints
'same as gymnasium' or the first difference. Used by test_ros_env.py.

    ros_env_vectorisers.py async-make | make_vec-async | sync-make | make_vec-sync [NUM_ENVS] [STEPS]
"""
import sys

import gymnasium
import numpy as np

from robot_ai.envs import RosCartPoleEnv  # noqa: F401  (the import registers robot_ai/RosCartPole-v1)

ENV = 'robot_ai/RosCartPole-v1'
VECTORISERS = {
    'async-make': lambda n: gymnasium.vector.AsyncVectorEnv([lambda: gymnasium.make(ENV)] * n),
    'make_vec-async': lambda n: gymnasium.make_vec(ENV, num_envs=n, vectorization_mode='async'),
    'sync-make': lambda n: gymnasium.vector.SyncVectorEnv([lambda: gymnasium.make(ENV)] * n),
    'make_vec-sync': lambda n: gymnasium.make_vec(ENV, num_envs=n, vectorization_mode='sync'),
}


def main() -> int:
    mode = sys.argv[1]
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 4
    steps = int(sys.argv[3]) if len(sys.argv) > 3 else 300
    ros = VECTORISERS[mode](n)
    ref = gymnasium.make_vec('CartPole-v1', num_envs=n, vectorization_mode='sync')
    rng = np.random.default_rng(5)
    try:
        o1, o2 = ros.reset(seed=5)[0], ref.reset(seed=5)[0]
        if not (o1 == o2).all():
            print(f'reset differs: {o1} {o2}')
            return 0
        for t in range(steps):
            a = rng.integers(2, size=n)
            r1, r2 = ros.step(a), ref.step(a)
            for x, y in zip(r1[:4], r2[:4]):
                if x.dtype != y.dtype or not (x == y).all():
                    print(f'step {t} differs: {r1[:4]} {r2[:4]}')
                    return 0
    finally:
        ros.close()
    print('same as gymnasium')
    return 0


if __name__ == '__main__':
    sys.exit(main())
