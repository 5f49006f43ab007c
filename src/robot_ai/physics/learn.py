"""Learning Push-v0 and PickAndPlace-v0 in minutes on a CPU: DAgger (behaviour cloning with the expert's
corrections) of the scripted expert (physics.expert) into a small MLP (physics.mlp), over many MuJoCo worlds stepped
together (ManipulationVectorEnv). No rospy, no torch.

    training = learn(ManipulationSetup('push', model='panda.urdf'), LearnSettings(minutes=10), seed=0)
    training.net.act_batch(x), training.best_success, training.history

Each round the worlds play one episode: the first ``expert_rounds`` driven by the expert (demonstrations), the rest
by the network, every step labelled with the expert's action where the network stood (DAgger: the network learns
what to do in the states its own mistakes lead to, which demonstrations alone never show it); then ``fit_steps``
Adam steps on batches of everything gathered (``max_samples`` most recent). Every ``eval_every`` rounds the network
plays ``eval_episodes`` episodes on goals it never trained on; the best network so far is kept, and learning stops
when it reaches ``target`` or the wall-clock budget (``minutes``) is spent.
"""
from __future__ import annotations

import dataclasses
import math
import time
from typing import Callable

import numpy as np

from robot_ai.physics.env import ManipulationSetup, ManipulationVectorEnv
from robot_ai.physics.mlp import Mlp

EVAL_SEED = 10 ** 6          # the held-out goals' seeds start here; training's are below
FINAL_SEED = 2 * 10 ** 6     # a finished training's own check, on goals neither saw


@dataclasses.dataclass(frozen=True)
class LearnSettings:
    """minutes: the wall-clock budget; rounds: the most rounds (None: as many as the minutes allow); worlds:
    simulated at once; hidden: the network's layers; the rest as the module's text says."""
    minutes: float = 30.0
    rounds: int | None = None
    worlds: int = 32
    hidden: tuple[int, int] = (256, 256)
    expert_rounds: int = 3
    fit_steps: int = 300
    batch: int = 256
    rate: float = 1e-3
    eval_every: int = 5
    eval_episodes: int = 64
    target: float | None = 0.98
    max_samples: int = 1_000_000

    def check(self) -> None:
        if not (isinstance(self.minutes, (int, float)) and math.isfinite(self.minutes) and self.minutes > 0):
            raise ValueError(f'minutes must be a positive number, got {self.minutes!r}')
        for name in ('worlds', 'expert_rounds', 'fit_steps', 'batch', 'eval_every', 'eval_episodes', 'max_samples'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f'{name} must be a whole number of at least 1, got {value!r}')
        if self.rounds is not None and (isinstance(self.rounds, bool) or not isinstance(self.rounds, int)
                                        or self.rounds < self.expert_rounds):
            raise ValueError(f'rounds must be a whole number of at least expert_rounds ({self.expert_rounds}), or '
                             f'None, got {self.rounds!r}')
        if len(self.hidden) != 2 or not all(isinstance(h, int) and 1 <= h <= 4096 for h in self.hidden):
            raise ValueError(f'hidden must be two layer widths from 1 to 4096, got {self.hidden!r}')
        if not (isinstance(self.rate, float) and 0 < self.rate < 1):
            raise ValueError(f'rate must be a number between 0 and 1, got {self.rate!r}')
        if self.target is not None and not 0 < self.target <= 1:
            raise ValueError(f'target must be a success rate in (0, 1], or None, got {self.target!r}')


@dataclasses.dataclass(frozen=True)
class Round:
    """One round: its number, seconds since the start, samples held, the last fit's loss, the share of the round's
    episodes that succeeded, and the held-out success rate where it was measured (None elsewhere)."""
    round: int
    seconds: float
    samples: int
    loss: float
    rollout_success: float
    eval_success: float | None


@dataclasses.dataclass(eq=False)
class Training:
    """What learn gives: the best network, the setup and settings, the seed, each round, the best held-out success
    and its round, the wall time and the env steps taken."""
    net: Mlp
    setup: ManipulationSetup
    settings: LearnSettings
    seed: int
    history: list[Round]
    best_success: float
    best_round: int
    elapsed: float
    steps: int


def flatten(obs: dict) -> np.ndarray:
    """A goal env's observations (N, ...) flattened as gymnasium.spaces.flatten does a Dict: achieved_goal,
    desired_goal, observation (29 numbers)."""
    return np.concatenate([obs['achieved_goal'], obs['desired_goal'], obs['observation']], axis=1)


def expert_policy(setup: ManipulationSetup) -> Callable[[np.ndarray], np.ndarray]:
    """The setup's scripted expert as a policy of flattened observations (flatten's layout), as evaluate takes
    one."""
    return lambda x: setup.expert(x[:, 6:], x[:, 3:6])


def evaluate(act_batch: Callable[[np.ndarray], np.ndarray], env: ManipulationVectorEnv, episodes: int,
             seed: int) -> tuple[float, float]:
    """(success rate, mean final distance) of act_batch (flattened observations -> actions) over episodes played on
    env's worlds from seeds seed, seed + 1, ..."""
    done, successes, distances = 0, [], []
    while done < episodes:
        obs, _ = env.reset(seed=seed + done)
        for _ in range(env.max_episode_steps):
            obs, _, _, _, info = env.step(act_batch(flatten(obs)))
        take = min(env.num_envs, episodes - done)
        successes.extend(info['is_success'][:take])
        distances.extend(np.linalg.norm(obs['achieved_goal'] - obs['desired_goal'], axis=1)[:take])
        done += take
    return float(np.mean(successes)), float(np.mean(distances))


def learn(setup: ManipulationSetup, settings: LearnSettings = LearnSettings(), seed: int = 0,
          on_round: Callable[[Round], None] | None = None,
          should_stop: Callable[[], bool] | None = None) -> Training:
    """DAgger of the expert into an MLP on setup's task (see the module's text); should_stop() true after a round:
    the run ends there (held-out success measured first), the best network so far kept."""
    settings.check()
    start = time.monotonic()
    env = ManipulationVectorEnv(settings.worlds, setup.task, setup=setup)
    net = Mlp.new(29, 4, settings.hidden, seed=seed)
    rng = np.random.default_rng(seed)
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    held = 0
    history: list[Round] = []
    best, best_net, best_round, steps, loss = -1.0, Mlp.from_arrays(net.arrays()), 0, 0, float('nan')
    budget = settings.minutes * 60.0
    for k in range(10 ** 9):
        obs, _ = env.reset(seed=seed * 10 ** 5 + k * settings.worlds)
        for _ in range(env.max_episode_steps):
            x = flatten(obs)
            expert = setup.expert(obs['observation'], obs['desired_goal'])
            xs.append(x)
            ys.append(expert)
            held += len(x)
            obs, _, _, _, info = env.step(expert if k < settings.expert_rounds else net.act_batch(x))
        steps += env.max_episode_steps * settings.worlds
        while held - len(xs[0]) >= settings.max_samples:      # the oldest go: memory stays bounded
            held -= len(xs.pop(0))
            ys.pop(0)
        if k + 1 >= settings.expert_rounds:
            x_all, y_all = np.concatenate(xs), np.concatenate(ys)
            if k + 1 == settings.expert_rounds:
                net.normalise_by(x_all)
            for _ in range(settings.fit_steps):
                rows = rng.integers(0, len(x_all), settings.batch)
                loss = net.fit_step(x_all[rows], y_all[rows], settings.rate)
        measured = None
        last = time.monotonic() - start >= budget or (should_stop is not None and should_stop()) or \
            (settings.rounds is not None and k + 1 >= settings.rounds)
        if k + 1 >= settings.expert_rounds and ((k + 1) % settings.eval_every == 0 or last):
            measured, _ = evaluate(net.act_batch, env, settings.eval_episodes, EVAL_SEED)
            steps += env.max_episode_steps * settings.eval_episodes
            if measured > best:       # the network only (its arrays), not the optimiser's moments
                best, best_net, best_round = measured, Mlp.from_arrays(net.arrays()), k + 1
        history.append(Round(k + 1, time.monotonic() - start, held, loss, float(np.mean(info['is_success'])),
                             measured))
        if on_round is not None:
            on_round(history[-1])
        if last or (measured is not None and settings.target is not None and measured >= settings.target):
            break
    return Training(best_net, setup, settings, seed, history, best, best_round, time.monotonic() - start, steps)
