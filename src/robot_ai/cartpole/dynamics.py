"""gymnasium's CartPole, batched over many episodes at once, and one state at a time. No rospy.

The constants and step limits are read from gymnasium's own environment (once per env id and process);
the equations are those of gymnasium's ``CartPoleEnv.step``, operation for operation, so that an episode
here has the length gymnasium's ``gym.make(env_id)`` gives from the same start state with the same actions
(tested on hundreds of episodes).

    dynamics = CartPoleDynamics.of('CartPole-v1')
    starts = start_states(np.random.default_rng(0), 3, 10)            # (3 candidates, 10 episodes, 4)
    lengths = dynamics.episode_lengths(starts, 500, weights=w)           # w (3, 4): a linear policy each
    state, terminated = dynamics.step(state, action)                     # one state, plain floats
    state, terminated = dynamics.step_force(state, force)                # any force in newtons (a ROS robot's)
"""
import functools
import math

import numpy as np

SUPPORTED_ENVS = ('CartPole-v0', 'CartPole-v1')
START_LOW, START_HIGH = -0.05, 0.05  # gymnasium's reset: each state variable uniform in [-0.05, 0.05)


class RequestError(ValueError):
    """A request outside what the agents allow; the message says what is allowed."""


class CartPoleDynamics:
    """gymnasium's CartPole: its constants, its step limit, and its equations of motion.

    Action space: 0 pushes the cart left, 1 pushes it right, with ``force_mag`` newtons.
    Observation: (x, x_dot, theta, theta_dot); gymnasium shows the agent the float32 of the float64 state.
    Episode end: |x| > ``x_threshold`` or |theta| > ``theta_threshold_radians`` (terminated), or the
    environment's step limit ``max_episode_steps`` (truncated).
    """

    def __init__(self, env_id: str = 'CartPole-v1'):
        import gymnasium as gym
        if env_id not in SUPPORTED_ENVS:
            try:
                gym.spec(env_id)
                known = True
            except Exception:
                known = False
            raise RequestError(f'env_id {env_id!r} is {"not a CartPole environment" if known else "unknown"}; '
                               f'allowed: {", ".join(SUPPORTED_ENVS)}')
        spec = gym.spec(env_id)
        env = make_env(env_id).unwrapped
        if getattr(env, 'kinematics_integrator', 'euler') != 'euler' or getattr(env, '_sutton_barto_reward', False):
            raise RequestError(f'{env_id} is configured differently from the course (euler, reward 1 a step)')
        self.env_id = env_id
        self.max_episode_steps = int(spec.max_episode_steps)
        self.gravity = float(env.gravity)
        self.masspole = float(env.masspole)
        self.total_mass = float(env.total_mass)
        self.length = float(env.length)                 # half the pole's length
        self.polemass_length = float(env.polemass_length)
        self.force_mag = float(env.force_mag)
        self.tau = float(env.tau)                       # seconds between state updates
        self.theta_threshold_radians = float(env.theta_threshold_radians)
        self.x_threshold = float(env.x_threshold)
        env.close()

    @staticmethod
    def of(env_id: str) -> 'CartPoleDynamics':
        """The dynamics of env_id, built once per process (gym.make is not free)."""
        return _dynamics_of(env_id)

    def resolve_max_steps(self, max_steps: int) -> int:
        """A request's max_steps: 0 = the environment's limit; above it or negative, RequestError."""
        max_steps = int(max_steps or self.max_episode_steps)
        if not 1 <= max_steps <= self.max_episode_steps:
            raise RequestError(f'max_steps must be 1 to {self.env_id}\'s limit {self.max_episode_steps} '
                               f'(0 = {self.max_episode_steps}), got {max_steps}')
        return max_steps

    def step(self, state, action: int) -> tuple[tuple[float, float, float, float], bool]:
        """One step of one episode: (the next state as a tuple of floats, terminated).

        Plain float arithmetic in gymnasium's order of operations (x * x is numpy's square), so the state is
        gymnasium's bit for bit; 20 times faster than numpy on one state."""
        return self.step_force(state, self.force_mag if action == 1 else -self.force_mag)

    def step_force(self, state, force: float) -> tuple[tuple[float, float, float, float], bool]:
        """One step with any force on the cart (newtons, + pushes toward +x) where gymnasium uses +-force_mag:
        (the next state, terminated). With force = +-force_mag it is gymnasium's step, bit for bit."""
        x, x_dot, theta, theta_dot = state
        costheta, sintheta = math.cos(theta), math.sin(theta)
        temp = (force + self.polemass_length * (theta_dot * theta_dot) * sintheta) / self.total_mass
        thetaacc = (self.gravity * sintheta - costheta * temp) / (
            self.length * (4.0 / 3.0 - self.masspole * (costheta * costheta) / self.total_mass))
        xacc = temp - self.polemass_length * thetaacc * costheta / self.total_mass
        x = x + self.tau * x_dot
        x_dot = x_dot + self.tau * xacc
        theta = theta + self.tau * theta_dot
        theta_dot = theta_dot + self.tau * thetaacc
        return (x, x_dot, theta, theta_dot), self.termination(x, theta) != ''

    def termination(self, x: float, theta: float) -> str:
        """Why gymnasium would terminate an episode in this state: 'pole fell', 'cart left the rail', or ''."""
        if theta < -self.theta_threshold_radians or theta > self.theta_threshold_radians:
            return 'pole fell'
        if x < -self.x_threshold or x > self.x_threshold:
            return 'cart left the rail'
        return ''

    def episode_lengths(self, starts, max_steps: int, weights=None, policy=None, rng=None) -> np.ndarray:
        """Lengths (C, E) of the episodes started at starts (C, E, 4), all stepped together.

        weights (C, 4): candidate c plays the course's linear policy ``obs.w_c > 0``.
        policy: a function of the observations (4, n) float32 of the n live episodes -> push right (n,) bool.
        Neither: random actions drawn from rng (the course's random-action baseline).
        Episodes that have ended leave the batch."""
        starts = np.asarray(starts, dtype=np.float64)
        c, e = starts.shape[:2]
        n = c * e
        s = starts.reshape(n, 4).T.copy()                      # rows x, x_dot, theta, theta_dot
        w = None if weights is None else np.repeat(np.asarray(weights, np.float64), e, axis=0).T.copy()
        alive = np.arange(n)
        lengths = np.full(n, max_steps, dtype=np.int64)
        gravity, masspole, total_mass, length = self.gravity, self.masspole, self.total_mass, self.length
        polemass_length, force_mag, tau = self.polemass_length, self.force_mag, self.tau
        x_threshold, theta_threshold = self.x_threshold, self.theta_threshold_radians
        for t in range(1, max_steps + 1):
            if w is not None:
                # the policy sees gymnasium's float32 observation, promoted exactly to float64 in the dot
                push = np.einsum('ij,ij->j', s.astype(np.float32), w) > 0
            elif policy is not None:
                push = policy(s.astype(np.float32))
            else:
                push = rng.random(len(alive)) < 0.5
            x, x_dot, theta, theta_dot = s
            force = np.where(push, force_mag, -force_mag)
            costheta, sintheta = np.cos(theta), np.sin(theta)
            # the same operations, in the same order, as gymnasium's CartPoleEnv.step
            temp = (force + polemass_length * np.square(theta_dot) * sintheta) / total_mass
            thetaacc = (gravity * sintheta - costheta * temp) / (
                length * (4.0 / 3.0 - masspole * np.square(costheta) / total_mass))
            xacc = temp - polemass_length * thetaacc * costheta / total_mass
            s = np.stack((x + tau * x_dot, x_dot + tau * xacc, theta + tau * theta_dot, theta_dot + tau * thetaacc))
            done = (np.abs(s[0]) > x_threshold) | (np.abs(s[2]) > theta_threshold)  # gymnasium's x < -t or x > t
            if done.any():
                lengths[alive[done]] = t
                keep = ~done
                alive, s = alive[keep], s[:, keep]
                if w is not None:
                    w = w[:, keep]
                if not len(alive):
                    break
        return lengths.reshape(c, e)


def make_env(env_id: str, **kwargs):
    """gymnasium.make(env_id, **kwargs) without gymnasium's DeprecationWarning for CartPole-v0: v0 is the course's
    env on purpose, and the warning landed in the middle of the demo's summary."""
    import warnings
    import gymnasium as gym
    with warnings.catch_warnings():
        warnings.filterwarnings('ignore', message='.*out of date', category=DeprecationWarning)
        return gym.make(env_id, **kwargs)


@functools.lru_cache(maxsize=None)
def _dynamics_of(env_id):
    return CartPoleDynamics(env_id)


def start_states(rng: np.random.Generator, count: int, episodes: int) -> np.ndarray:
    """gymnasium's reset distribution for (count, episodes) episodes: shape (count, episodes, 4)."""
    return rng.uniform(START_LOW, START_HIGH, size=(count, episodes, 4))


def rng_for(seed: int) -> np.random.Generator:
    """numpy's default_rng for any integer seed: negative seeds (ROS int64) map to distinct non-negative ones,
    and a non-negative seed is used as it is."""
    return np.random.default_rng(int(seed) % (2 ** 64))


def check_state(state, what: str = 'state') -> np.ndarray:
    """4 finite floats, one per state variable (a state, or a linear policy's weights), or RequestError."""
    s = np.asarray(state, dtype=np.float64).reshape(-1)
    if s.shape != (4,):
        raise RequestError(f'{what} must be 4 numbers (x, x_dot, theta, theta_dot), got {s.size}')
    if not np.isfinite(s).all():
        raise RequestError(f'{what} must be finite numbers, got {[float(v) for v in s]}')
    return s


FLOAT32_MAX = float(np.finfo(np.float32).max)


def check_observation(state) -> np.ndarray:
    """A state a policy can act on (both kinds: one rule, one message): 4 finite numbers whose float32, gymnasium's
    observation type, is finite too. Returns them as float64."""
    s = check_state(state)
    if np.abs(s).max() > FLOAT32_MAX:
        raise RequestError(f'state must be within float32 range (|v| <= {FLOAT32_MAX:.3g}): a policy sees '
                           f'gymnasium\'s float32 observation, got {[float(v) for v in s]}')
    return s
