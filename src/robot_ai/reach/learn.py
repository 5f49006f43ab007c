"""ARS learns an arm's reach task; held-out evaluation; the P-controller it is measured against; policy files. No rospy.

    training = train(dict(model='/path/arm.urdf', tip='tool0'), seed=0, progress=print)   # seconds, on 2 cores
    training.policy.act(flat_observation), training.held_out.success_rate
    path = policy_files.save(training, '/tmp/reach.npz')

The policy is ARS's linear policy (robot_ai.ars) on the flattened goal-env observation (achieved goal, desired goal,
joint positions, tip). ARS learns on the dense reward (minus the distance, every step). Its observation statistics
are chosen so that the P-controller on the tip error lies in the class and exploration acts through the goal: the
x, y and z of the achieved goal, the desired goal and the tip share one mean and standard deviation each (seeded with
the distribution of goals, which is known), and the joint positions are scaled by JOINT_SCALE times their range, so
that joint terms stay small corrections (measured here: with each joint's own statistics the joint weights
random-walk into 5-8 cm offsets and ARS stalls near 90 % on the Panda; at 3 x the range a 2.8 m industrial arm
still missed 15 %). The weights of the achieved goal, the desired goal and the tip sum to zero, x, y and z apart
(ars.train's zero_sum): the action answers the error, not where the goal is (free, their sum random-walked too, and a
2.7 m KUKA KR210 stopped 5-13 cm short of 2 % of goals from random starts). alpha and nu shrink over the run
(decay). A large arm's step is several times the 5 cm
threshold, so it needs finer weights: the default number of iterations grows with ee_step / distance_threshold
(80 for a UR5, 121 for a 2.8 m arm; default_settings).

Pose goals (goal='pose'): the orientation error (the rotation from the tip's orientation to the goal's) is a
product of the two quaternions, which no linear map of the observation gives. ARS's linear policy then acts on fixed
features of the flattened observation (PoseFeatures: the achieved and desired positions, that rotation vector, the
joints), a layer the policy carries (FeaturePolicy), so that the P-controller on the pose error lies in the class
again; HER's relabelling is unaffected (the features are computed from the goals the policy is given).

Its policy files (save, load) are robot_ai.reach.policy_files'.
"""
from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field, replace

import numpy as np

import gymnasium
from gymnasium import spaces
from gymnasium.wrappers.vector import TransformObservation

from robot_ai import ars
from robot_ai.reach.env import ReachSetup, ReachVectorEnv
from robot_ai.reach.task import goal_distance, rotation_error, why_unreached

JOINT_SCALE = 10.0              # joint positions normalised by 10 x their range (see the module's docstring)
PRIOR_STATES = 2000             # random configurations and goals that seed the goal coordinates' statistics
HELD_OUT_EPISODES = 1000
HELD_OUT_SEED = 2 ** 31         # held-out goals: seeds no training iteration draws (those are below 2 ** 31)
CHAIN_ENVS = 100               # chained evaluation: this many arms, each through its episodes one after another
MISSES = {'beyond': 'beyond the arm\'s reach', 'collision': 'blocked by a collision',
          'limits': 'stalled at joint limits', 'other': 'stalled elsewhere', 'turn': 'at the goal, not turned to it'}
ROTATION_SCALE = 1.0            # rad: the orientation error's fixed statistics (mean 0, this std)
SETTINGS = ars.ARSSettings(iterations=80, directions=32, top_directions=16, step_size=0.1, noise=0.1, episodes=8,
                           eval_episodes=256, decay=0.9, bias=True, normalize=True)


@dataclass(frozen=True)
class PoseFeatures:
    """A pose goal's policy inputs from the flattened goal-env observation (achieved goal 0-6, desired goal 7-13,
    joints 14 .. 13 + n, tip): the achieved position (3), the desired one (3), the rotation vector from the achieved
    orientation to the desired one (3, rad, base frame: task.rotation_error) and the joints (n)."""
    n: int

    @property
    def size(self) -> int:
        return 9 + self.n

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        a, d = x[:, :7], x[:, 7:14]
        return np.concatenate((a[:, :3], d[:, :3], rotation_error(a, d), x[:, 14:14 + self.n]), axis=1)

    def space(self) -> spaces.Box:
        return spaces.Box(-np.inf, np.inf, (self.size,), np.float64)


@dataclass
class FeaturePolicy:
    """A linear policy (ars.LinearPolicy) on fixed features of the flattened observation: act_batch(x) is
    linear.act_batch(features(x)). Its arrays are the linear policy's (a policy file holds those, kind ars_linear;
    robot_ai.reach.policy_files puts the features back on load from the env it names)."""
    linear: ars.LinearPolicy
    features: PoseFeatures

    kind = 'ars_linear'

    def __getattr__(self, name):                 # weights, obs_mean, obs_std, bias, low, high, choices
        if name in ('linear', 'features'):
            raise AttributeError(name)
        return getattr(self.linear, name)

    def act_batch(self, x: np.ndarray) -> np.ndarray:
        return self.linear.act_batch(self.features(np.atleast_2d(np.asarray(x, dtype=np.float64))))

    def act(self, x) -> np.ndarray:
        return self.act_batch(np.asarray(x, dtype=np.float64).reshape(1, -1))[0]


def features_of(setup: ReachSetup) -> PoseFeatures | None:
    """The fixed features a policy for setup's task acts on: PoseFeatures for pose goals, None for positions."""
    return PoseFeatures(setup.arm.n) if setup.pose else None


def with_features(policy, setup: ReachSetup):
    """policy (an ars.LinearPolicy) as it acts on setup's flattened observations."""
    features = features_of(setup)
    return policy if features is None or isinstance(policy, FeaturePolicy) else FeaturePolicy(policy, features)


def _feature_env(env, features: PoseFeatures):
    space = features.space()
    return TransformObservation(env, lambda obs: features(ars.flatten_batch(env.single_observation_space, obs)),
                                gymnasium.vector.utils.batch_space(space, env.num_envs), space)


def _feature_distance(features: np.ndarray) -> np.ndarray:
    d = features[:, 3:6] - features[:, 0:3]
    return np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])


@dataclass
class Evaluation:
    """A policy over fresh goals: the success rate (tip within the threshold at the last step), the final
    distances (episodes,), the seed of the first episode, where episodes started ('home', 'random' or 'chained'),
    and the goals missed by reason (beyond reach, the last motion refused by a collision, at joint limits, none of
    these: MISSES' keys); planned: the share of the goals reached whose episode took a planned way round (the
    planner's share; the policy's is the rest)."""
    success_rate: float
    distances: np.ndarray
    seed: int
    start: str = 'home'
    misses: dict[str, int] = field(default_factory=dict)
    planned: float = 0.0

    @property
    def mean_distance(self) -> float:
        return float(self.distances.mean())

    def misses_text(self) -> str:
        """The misses by reason in a few words, '' without any."""
        return ', '.join(f'{count} {MISSES[reason]}' for reason, count in self.misses.items() if count)


@dataclass
class Training:
    """An ARS run on a reach task: the setup, ARS's result, the best policy's held-out evaluation and the
    P-controller's on the same goals."""
    setup: ReachSetup
    env_kwargs: dict
    result: ars.ARSResult
    held_out: Evaluation | None = None
    p_controller: Evaluation | None = None
    seed: int = 0
    wall_time: float = 0.0
    notes: list[str] = field(default_factory=list)

    @property
    def policy(self) -> ars.LinearPolicy:
        return self.result.policy


def default_settings(setup: ReachSetup) -> ars.ARSSettings:
    """SETTINGS with as many iterations as setup's arm needs: 80 x (ee_step / distance_threshold) ** 0.3, at least
    80."""
    ratio = max(1.0, setup.ee_step / setup.task.distance_threshold)
    return replace(SETTINGS, iterations=int(round(SETTINGS.iterations * ratio ** 0.3)))


def env_kwargs_of(setup: ReachSetup, kwargs: dict) -> dict:
    """The kwargs that make setup's env again, as a policy file keeps them: the model's absolute path and xacro
    arguments, and every setting resolved (ee_step, damping, home)."""
    out = dict(model=setup.model.path or None, xacro_args=' '.join(f'{k}:={v}' for k, v in setup.model.xacro_args),
               **setup.settings())
    out.pop('reward_type')
    return out


def statistics(setup: ReachSetup, rng_seed: int = 1) -> tuple[list[list[int]], dict, np.ndarray]:
    """(shared groups, fixed statistics, prior states) of ARS's normalisation for setup's flattened observation:
    achieved goal (0-2), desired goal (3-5), joints (6 .. 6 + n - 1), tip (6 + n .. 8 + n); for pose goals, of
    PoseFeatures: achieved (0-2), desired (3-5), rotation (6-8, fixed), joints (9 ..)."""
    arm, n = setup.arm, setup.arm.n
    rng = np.random.default_rng(rng_seed)
    q = rng.uniform(arm.lower, arm.upper, (PRIOR_STATES, n))
    goals = arm.tip_positions(rng.uniform(arm.lower, arm.upper, (PRIOR_STATES, n)))
    tips = arm.tip_positions(q)
    joints = {j: (float(setup.home[j]), float(JOINT_SCALE * (arm.upper[j] - arm.lower[j]))) for j in range(n)}
    if setup.pose:
        groups = [[i, 3 + i] for i in range(3)]
        fixed = {9 + j: v for j, v in joints.items()}
        fixed.update({6 + i: (0.0, ROTATION_SCALE) for i in range(3)})
        return groups, fixed, np.concatenate((tips, goals, np.zeros((PRIOR_STATES, 3)), q), axis=1)
    groups = [[i, 3 + i, 6 + n + i] for i in range(3)]
    fixed = {6 + j: v for j, v in joints.items()}
    return groups, fixed, np.concatenate((tips, goals, q, tips), axis=1)


def final_distance(observations: dict) -> np.ndarray:
    return goal_distance(observations['achieved_goal'], observations['desired_goal'])


def train(env_kwargs: dict | None = None, settings: ars.ARSSettings | None = None, seed: int = 0, progress=None,
          should_stop=None, target_success: float | None = None,
          evaluate_episodes: int = HELD_OUT_EPISODES, chunks: int = 0, ray_address: str = '') -> Training:
    """ARS on the reach task of env_kwargs (ReachEnv's: model, xacro_args, tip, control, start, ...), reproducible from
    seed. progress(ars.IterationStats) after each iteration; should_stop() before each (cancel keeps the best so
    far); target_success: stop once an iteration's evaluation reaches it. settings: default_settings(the arm's).
    Ends with the held-out evaluation of the
    best policy and of the P-controller (ee control) over evaluate_episodes fresh goals (0: none). chunks, ray_address:
    the rollouts in that many envs, kept by actors on a Ray cluster (ars.train): from home or random starts the same
    numbers as one env here.

    The rollouts run without the limit recovery (ReachSetup.recover), the policy's own steps only: an episode the
    recovery takes over from a perturbed policy says nothing of its weights, and ARS learned worse through it (the
    KUKA's pose goals: 85.9 % from home where it learns 95.0 % without). The held-out evaluations, the policy file
    and the arm have the recovery around the policy, as the setup asks."""
    kwargs = {k: v for k, v in (env_kwargs or {}).items() if k != 'reward_type'}
    t0 = time.monotonic()
    setup = ReachSetup(**kwargs)
    settings = settings or default_settings(setup)
    groups, fixed, prior = statistics(setup)
    reached = {'done': False}

    def on_iteration(stats: ars.IterationStats) -> None:
        if target_success is not None and stats.success_rate >= target_success:
            reached['done'] = True
        if progress is not None:
            progress(stats)

    def stop() -> bool:
        return reached['done'] or (should_stop is not None and should_stop())

    features = features_of(setup)
    rollouts = {**kwargs, 'limit_recovery': False}
    if features is None:
        make_env, metric = (lambda k: ReachVectorEnv(k, reward_type='dense', **rollouts)), final_distance
    else:
        make_env = lambda k: _feature_env(ReachVectorEnv(k, reward_type='dense', **rollouts), features)  # noqa: E731
        metric = _feature_distance
    result = ars.train(make_env, settings, seed, progress=on_iteration, should_stop=stop, shared_statistics=groups,
                       final_metric=metric, prior_states=prior, fixed_statistics=fixed, chunks=chunks,
                       ray_address=ray_address, zero_sum=groups)
    if reached['done']:
        result.cancelled = False
    if features is not None:
        result.policy = FeaturePolicy(result.policy, features)
        result.last_policy = FeaturePolicy(result.last_policy, features)
    training = Training(setup, env_kwargs_of(setup, kwargs), result, seed=seed)
    if evaluate_episodes:
        training.held_out = evaluate(result.policy, setup, evaluate_episodes)
        if setup.control == 'ee':
            training.p_controller = evaluate(p_controller(setup), setup, evaluate_episodes)
    training.wall_time = time.monotonic() - t0
    return training


def evaluate(policy, setup: ReachSetup, episodes: int = HELD_OUT_EPISODES, seed: int = HELD_OUT_SEED,
             batch: int = 4096, start: str | None = None) -> Evaluation:
    """policy (anything with act_batch(flat observations) -> actions) over `episodes` fresh goals of setup's task,
    env i seeded seed + i, all in one vector env (or batches of `batch`). start: where episodes start instead of
    setup's ('home', 'random', or 'chained': CHAIN_ENVS arms each reach their goals one after another, every
    episode from where the last one left the arm)."""
    start = start or setup.start
    if start != setup.start:
        setup = copy.copy(setup)
        setup.start = start
    chained = start == 'chained'
    width = min(episodes, CHAIN_ENVS if chained else batch)
    distances, successes, goals, configurations, blocked, planned = [], [], [], [], [], []
    for first in range(0, episodes, width if not chained else episodes):
        k = min(width, episodes - first)
        env = ReachVectorEnv(k, setup=setup)
        obs, _ = env.reset(seed=seed + first)
        space = env.single_observation_space
        for chain in range(-(-episodes // k) if chained else 1):
            if chain:                                        # the autoreset step: the next goal, the arm where it is
                obs, *_ = env.step(np.zeros(env.action_space.shape, dtype=np.float32))
            took = np.zeros(k, dtype=bool)
            for _ in range(env.max_episode_steps):
                obs, _, _, _, infos = env.step(policy.act_batch(ars.flatten_batch(space, obs)))
                took |= env._recovery.planned()
            planned.append(took)
            distances.append(final_distance(obs))
            successes.append(infos['is_success'])
            blocked.append(infos.get('collision', np.zeros(k, dtype=bool)))     # its last motion was refused
            goals.append(obs['desired_goal'])
            configurations.append(env._q.T.copy())
        env.close()
    distances, successes = np.concatenate(distances)[:episodes], np.concatenate(successes)[:episodes]
    goals, configurations = np.concatenate(goals)[:episodes], np.concatenate(configurations)[:episodes]
    blocked = np.concatenate(blocked)[:episodes]
    misses = dict.fromkeys(MISSES, 0)
    for i in np.flatnonzero(~successes):
        if setup.pose and distances[i] < setup.task.distance_threshold:
            misses['turn'] += 1
            continue
        kind = why_unreached(setup.arm, goals[i][:3], configurations[i], float(distances[i]))[0]
        misses['collision' if blocked[i] and kind != 'beyond' else kind] += 1
    planned = np.concatenate(planned)[:episodes]
    share = float((planned & successes).sum() / max(int(successes.sum()), 1))
    return Evaluation(float(successes.mean()), distances, seed, start, misses, share)


def p_controller(setup: ReachSetup, gain: float = 1.0):
    """The plain P-controller on the tip error, action = clip(gain (goal - tip) / ee_step, -1, 1), as an ars_linear
    policy (weights on the desired and achieved goal only): the baseline a learned reach policy is measured against.
    Pose goals: also the turn, clip(gain rotation_error / angle_step), on PoseFeatures (a FeaturePolicy)."""
    d = 9 + setup.arm.n
    a = 6 if setup.pose else 3
    weights = np.zeros((a, d))
    k = gain / setup.ee_step
    for i in range(3):
        weights[i, i], weights[i, 3 + i] = -k, k
    if setup.pose:
        for i in range(3):
            weights[3 + i, 6 + i] = gain / setup.angle_step
    linear = ars.LinearPolicy(weights, np.zeros(d), np.ones(d), np.zeros(a), -np.ones(a), np.ones(a))
    return with_features(linear, setup)


def record_video(policy, setup: ReachSetup, path: str, episodes: int = 3, seed: int = HELD_OUT_SEED) -> str:
    """An mp4 of the arm reaching `episodes` fresh goals with policy (act_batch), drawn from the kinematics
    (robot_ai.reach.render), written whole or not at all."""
    from robot_ai.artifacts import write_video
    from robot_ai.reach.env import RENDER_FPS
    from robot_ai.reach.render import ArmRenderer
    renderer = ArmRenderer(setup.arm, setup.task.distance_threshold)

    def frames():
        for episode in range(episodes):
            env = ReachVectorEnv(1, setup=setup)
            obs, _ = env.reset(seed=seed + episode)
            renderer.new_episode()
            renderer.title = f'{setup.model.tree.name}: goal {episode + 1} of {episodes}'
            yield renderer.draw(env._q[:, 0], env._goal[:3, 0])
            for _ in range(env.max_episode_steps):
                obs, *_ = env.step(policy.act_batch(ars.flatten_batch(env.single_observation_space, obs)))
                yield renderer.draw(env._q[:, 0], env._goal[:3, 0])
            for _ in range(RENDER_FPS // 2):         # a pause on the result before the next goal
                yield renderer.draw(env._q[:, 0], env._goal[:3, 0])
    try:
        return write_video(path, frames(), RENDER_FPS)
    finally:
        renderer.close()
