"""What the cart-pole's runs leave behind: their plot jobs, CSV logs and videos (written by robot_ai.artifacts). No
rospy.

    write_plot(search_plot_job(result), stem + '.png');  write_csv(stem + '.csv', *search_log(result))
    record_video('CartPole-v1', policy.act, 500, seed=0, path=stem + '.mp4')
"""
import os

import numpy as np

from robot_ai.artifacts import write_video


def search_plot_job(result) -> dict:
    """The learning curve of a linear_search.SearchResult: every candidate's average length, the best so far,
    the random-action baseline and the step limit."""
    avgs = [float(v) for v in result.avg_lengths]
    hlines = []
    if np.isfinite(result.baseline_avg_length):
        hlines.append(dict(y=result.baseline_avg_length, label=f'random actions ({result.baseline_avg_length:.1f})',
                           color='tab:gray', ls='--'))
    hlines.append(dict(y=result.max_steps, label=f'step limit ({result.max_steps})', color='tab:red', ls=':'))
    return dict(
        title=f'{result.env_id} random search, seed {result.seed}: best {result.best_avg_length:.1f}, '
              f'final {result.final_avg_length:.1f}',
        xlabel='candidate (iteration)', ylabel=f'average episode length over {result.episodes} episodes',
        series=[dict(y=avgs, label='candidate average length', style='points', color='tab:blue'),
                dict(y=[float(v) for v in np.maximum.accumulate(avgs)] if avgs else [], label='best so far',
                     style='step', color='tab:orange', lw=2)],
        hlines=hlines, ylim=[0, result.max_steps * 1.05], integer_x=True)


def ars_plot_job(result, settings, search, env_id: str, final_average: float) -> dict:
    """ARS's learning curve beside the course's random search, against the episodes each played (log scale): ARS's
    average length of its perturbed policies per iteration, the random search's best candidate so far."""
    per_iteration = 2 * settings.directions * settings.episodes
    ars_x = [per_iteration * (i + 1) for i in range(len(result.history))]
    search_x = [search.episodes * (i + 1) for i in range(len(search.avg_lengths))]
    return dict(
        title=f'{env_id}: ARS (final average {final_average:.1f}) and the course\'s random search (final average '
              f'{search.final_avg_length:.1f}), seed {result.seed}',
        xlabel='episodes played (log scale)', ylabel='average episode length', xscale='log',
        series=[dict(x=ars_x, y=[float(h.rollout_return) for h in result.history], style='line', color='tab:orange',
                     lw=2, label=f'ARS: its perturbed policies ({settings.directions} directions x 2)'),
                dict(x=search_x, y=[float(v) for v in np.maximum.accumulate(search.avg_lengths)], style='step',
                     color='tab:blue', lw=2, label=f'random search: best so far ({search.episodes} episodes each)')],
        hlines=[dict(y=search.max_steps, label=f'step limit ({search.max_steps})', color='tab:red', ls=':')],
        ylim=[0, search.max_steps * 1.05])


def q_learning_plot_job(result) -> dict:
    """The learning curves of a q_learning.TrainingResult: learner 0's total reward per episode and its running
    average of 100, every other learner's running average as a faint line, the random-action baseline."""
    from robot_ai.cartpole.q_learning import running_average, RBF_GAMMAS
    t = result.training
    rewards = [np.asarray(r, dtype=np.float64) for r in result.total_rewards]
    others = f'learners 1-{len(rewards) - 1}' if len(rewards) > 2 else 'learner 1'
    series = [dict(y=[float(v) for v in running_average(r)], style='line', color='tab:blue', alpha=0.3, lw=1,
                   label=f'{others}: running average of 100' if j == 1 else None)
              for j, r in enumerate(rewards) if j > 0]
    series += [dict(y=[float(v) for v in rewards[0]], style='points', color='tab:gray', ms=3,
                    label='learner 0: total reward per episode'),
               dict(y=[float(v) for v in running_average(rewards[0])], style='line', color='tab:orange', lw=2.5,
                    label='learner 0: running average of 100')]
    best = t.max_steps if t.bootstrap_at_time_limit else t.max_steps - 1
    spread = (f'{len(result.last100_averages)} learners, last-100 average {result.mean_last100:.1f} '
              f'$\\pm$ {result.ci95_last100:.1f}' if len(result.last100_averages) > 1   # mathtext: a real +-
              else f'last-100 average {result.mean_last100:.1f}')
    if len(result.greedy_averages):
        greedy = result.greedy_averages
        spread += (f'; final greedy agents: {greedy.min():.1f} to {greedy.max():.1f} steps' if len(greedy) > 1
                   else f'; final greedy agent: {greedy[0]:.1f} steps')
        from robot_ai.cartpole.q_learning import collapsed_learners
        bad = collapsed_learners(result)
        if bad:   # a line of its own, short enough for the plot's width
            spread += (f'\ncollapsed at the end of training: {"learners" if len(bad) > 1 else "learner"} '
                       f'{", ".join(map(str, bad))} (greedy far below last-100)')
    if result.failed:   # their curves stop where their processes did
        spread += (f'\n{"learners" if len(result.failed) > 1 else "learner"} {", ".join(map(str, result.failed))} '
                   'failed: the curve stops where the process did')
    return dict(
        title=f'{result.env_id} Q-learning, {t.regressor} regressor, {len(RBF_GAMMAS)} x {t.components} RBF features, '
              f'seed {result.seed}\n{spread}',
        xlabel='episode', ylabel='total reward (+1 steps)', series=series,
        hlines=[dict(y=result.baseline_total_reward, label=f'random actions ({result.baseline_total_reward:.1f})',
                     color='tab:gray', ls='--'),
                dict(y=best, label=f'the most an episode can total ({best})', color='tab:red', ls=':')],
        ylim=[0, t.max_steps * 1.05], integer_x=True)


def search_log(result) -> tuple[list, list]:
    """(header, rows) of a search's CSV log: one row per candidate evaluated."""
    header = ['candidate', 'w_x', 'w_x_dot', 'w_theta', 'w_theta_dot', 'avg_length']
    return header, [[i + 1] + [repr(float(v)) for v in w] + [repr(float(a))]
                    for i, (w, a) in enumerate(zip(result.weights, result.avg_lengths))]


def q_learning_log(result) -> tuple[list, list]:
    """(header, rows) of a training's CSV log: one row per episode per learner, learners in order."""
    from robot_ai.cartpole.q_learning import epsilon
    header = ['learner', 'seed', 'episode', 'total_reward', 'epsilon']
    return header, [[j, result.seed + j, n + 1, int(total), repr(epsilon(n))]
                    for j, totals in enumerate(result.total_rewards) for n, total in enumerate(totals)]


def record_video(env_id: str, policy, max_steps: int, seed: int, path: str) -> tuple[str, int]:
    """mp4 of one episode rendered by gymnasium (rgb_array), written whole or not at all (write_video); returns
    (path, steps). policy(observation) -> action (0 or 1); the start state comes from gymnasium's reset(seed)."""
    os.environ.setdefault('SDL_VIDEODRIVER', 'dummy')
    os.environ.setdefault('SDL_AUDIODRIVER', 'dummy')
    from robot_ai.cartpole.dynamics import make_env
    env = make_env(env_id, render_mode='rgb_array', max_episode_steps=max_steps)
    steps = 0

    def frames():
        nonlocal steps
        obs, _ = env.reset(seed=int(seed) % (2 ** 32))
        yield env.render()
        done = False
        while not done:
            obs, _, terminated, truncated, _ = env.step(policy(obs))
            steps += 1
            done = terminated or truncated
            yield env.render()
    try:
        write_video(path, frames(), env.metadata['render_fps'])
    finally:
        env.close()
    return path, steps
