"""ee control's limit recovery (issue 38, reach from wherever the arm stands): a step that a joint limit blocks, or an
arm stalled in a local minimum, sends the arm in joint space to a configuration that reaches the goal, once an
episode, and the policy goes on from there. No roscore."""
import os
from dataclasses import replace

import gymnasium
import numpy as np
import pytest

import robot_ai.reach  # noqa: F401 (registers robot_ai/Reach-v0)
from fk_helpers import robot_path
from robot_ai import ars
from robot_ai.reach import ReachEnv, ReachError, ReachSetup, ReachVectorEnv, env, learn, policy_files
from robot_ai.reach.env import READY, RECOVERED, RECOVERING, RECOVERY_ARRIVED, Recoveries, Recovery
from robot_ai.reach.safety import Limits
from test_reach import XACRO_ARM, assert_same, make_sync

UR5 = robot_path('ur5.urdf')
KUKA = robot_path('kuka_lwr_arm.urdf')
WORLD = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', 'world.yaml')
ARMS = [UR5, KUKA, robot_path('panda.urdf'), robot_path('pr2.urdf')]


@pytest.mark.parametrize('path', ARMS)
def test_the_p_controller_reaches_from_anywhere_with_the_recovery_and_not_without(path):
    """From random starts and chained, 500 goals each: at least 99 % with the recovery; without it the same
    controller stalls at joint limits (from random starts on more than 3 %: the reference the recovery is measured
    against)."""
    for start in ('random', 'chained'):
        setup = ReachSetup(model=path)
        plain = ReachSetup(model=path, limit_recovery=False)
        with_it = learn.evaluate(learn.p_controller(setup), setup, 500, start=start)
        without = learn.evaluate(learn.p_controller(plain), plain, 500, start=start)
        assert with_it.success_rate >= 0.99, (start, with_it)
        assert without.success_rate < with_it.success_rate and without.misses['limits'] > 0, (start, without)
        if start == 'random':
            assert without.success_rate < 0.97, without


def episode(env: ReachEnv, seed: int, steps: int = 50):
    """The P-controller's episode of seed in env: (info of the last step, the recovery after each step, the joints
    after each step)."""
    obs, _ = env.reset(seed=seed)
    p = learn.p_controller(env.setup)
    recoveries, joints = [], []
    for _ in range(steps):
        a = p.act_batch(ars.flatten_batch(env.observation_space, {k: v[None] for k, v in obs.items()}))[0]
        obs, _, _, _, info = env.step(a)
        recoveries.append(env._recovery)
        joints.append(env.joint_positions)
    return info, recoveries, joints


def test_a_base_turned_to_its_limit_the_short_way_round_goes_round_in_joint_space_and_reaches():
    """A random start of the UR5's (seed 24: its base at 4.70 rad of its +-2 pi) whose goal lies beyond +2 pi the
    short way round: damped least squares turns the base onto its limit, where the tip stalls. With the recovery the
    arm goes once, in joint space, to a configuration whose tip is at the goal (reaching_configuration), then the
    policy has it again and the goal is reached."""
    plain = ReachEnv(model=UR5, start='random', limit_recovery=False)
    info, recoveries, _ = episode(plain, 24)
    assert not info['is_success'] and plain.arm.at_limits(plain.joint_positions) == ['shoulder_pan_joint']
    assert {r.state for r in recoveries} == {READY}
    env = ReachEnv(model=UR5, start='random')
    info, recoveries, joints = episode(env, 24)
    assert info['is_success'] and not env.arm.at_limits(env.joint_positions)
    states = [r.state for r in recoveries]
    first, last = states.index(RECOVERING), len(states) - states[::-1].index(RECOVERING)
    assert set(states[:first]) == {READY} and set(states[last:]) == {RECOVERED}       # once, then the policy again
    assert abs(joints[first - 1][0] - env.arm.upper[0]) < 1e-3          # it began with the base at its limit
    to = np.array(recoveries[first].q)
    half = (env.arm.upper - env.arm.lower) / 2
    assert (np.abs(joints[last] - to) <= RECOVERY_ARRIVED * half + 1e-12).all()      # arrived where it went
    tip = env.arm.tip_positions(to[None])[0]
    assert np.linalg.norm(tip - env.unwrapped._goal) < env.setup.task.distance_threshold   # and that reaches the goal
    steps = np.abs(np.diff(np.array(joints[first - 1:last + 1]), axis=0))
    assert (steps <= 0.15 * half + 1e-12).all()       # in steps of at most RECOVERY_STEP of a half range


def test_an_arm_stalled_away_from_its_limits_goes_round_too_and_random_actions_seldom_stall():
    """Pose goals on the UR5 from home: the P-controller stalls short of one goal in ten with no joint at a limit (the
    position and the turn hold each other in a local minimum). With the recovery it reaches at least 99 % of 500
    goals, less than 95 % without. In such an episode the arm goes round once, after stall_steps steps that asked
    toward the goal without progress, no joint at a limit, and reaches. Random actions ask toward the goal seldom
    enough that a stall takes few of their episodes (each search costs as much as many steps): under 2 % from home;
    from random starts, where joint limits block them, under 10 %."""
    setup = ReachSetup(model=UR5, goal='pose')
    plain = ReachSetup(model=UR5, goal='pose', limit_recovery=False)
    with_it = learn.evaluate(learn.p_controller(setup), setup, 500)
    without = learn.evaluate(learn.p_controller(plain), plain, 500)
    assert with_it.success_rate >= 0.99 and without.success_rate < 0.95, (with_it, without)
    assert without.misses['other'] > without.misses['limits'], without
    stalled = ReachEnv(model=UR5, goal='pose', limit_recovery=False)
    seed = next(s for s in range(100) if not episode(stalled, s)[0]['is_success']
                and not stalled.arm.at_limits(stalled.joint_positions))
    env = ReachEnv(model=UR5, goal='pose')
    info, recoveries, joints = episode(env, seed)
    assert info['is_success'], seed
    states = [r.state for r in recoveries]
    first = states.index(RECOVERING)
    assert set(states[:first]) == {READY} and states[-1] == RECOVERED, states
    assert recoveries[first].since >= env.setup.stall_steps and not env.arm.at_limits(joints[first - 1])
    for kwargs, most in ((dict(), 0.02), (dict(goal='pose'), 0.02), (dict(start='random'), 0.1)):
        vec = ReachVectorEnv(1000, model=UR5, **kwargs)
        vec.reset(seed=0)
        rng, taken = np.random.default_rng(1), np.zeros(1000, dtype=bool)
        for _ in range(50):
            vec.step(rng.uniform(-1, 1, vec.action_space.shape).astype(np.float32))
            taken |= vec._recovery.state != READY
        assert taken.mean() < most, (kwargs, taken.mean())


def test_reaching_configurations_reach_goals_the_local_steps_miss_from_where_the_arm_stands():
    """reaching_configuration against the P-controller from the arm's own start (no recovery), 300 random starts and
    goals on the KUKA LWR: every answer within the limits, and it reaches at least 99 % of the goals, more than the
    local steps from where the arm stood; for pose goals too, and the answer does not depend on the batch."""
    for goal in ('position', 'pose'):
        setup = ReachSetup(model=robot_path('kuka_lwr_arm.urdf'), start='random', goal=goal, limit_recovery=False)
        local = learn.evaluate(learn.p_controller(setup), setup, 300, start='random')
        rng = np.random.default_rng(5)
        q = rng.uniform(setup.arm.lower, setup.arm.upper, (300, setup.arm.n)).T
        goals = setup.goals_of(rng.uniform(setup.arm.lower, setup.arm.upper, (300, setup.arm.n)).T)
        to = setup.reaching_configuration(goals, q)
        assert ((to >= setup.arm.lower[:, None]) & (to <= setup.arm.upper[:, None])).all()
        reached = setup.task.outcome(setup.goals_of(to).T, goals.T)[1].mean()
        assert reached >= 0.99 and reached > local.success_rate, (goal, reached, local.success_rate)
        np.testing.assert_array_equal(setup.reaching_configuration(goals[:, 7:8], q[:, 7:8])[:, 0], to[:, 7])


def test_the_recovery_of_one_arm_equals_the_batchs_and_envs_equal_sync_vector_env_bit_for_bit():
    """recover_one's numbers are recover's on a batch bit for bit, and ReachVectorEnv equals SyncVectorEnv from random
    starts and chained while arms recover (position and pose goals)."""
    setup = ReachSetup(model=UR5)
    rng = np.random.default_rng(3)
    stalled = ReachVectorEnv(200, model=UR5, start='random', limit_recovery=False)   # arms where the local steps
    obs, _ = stalled.reset(seed=0)                                                  # left them: some at limits
    for _ in range(30):
        obs = stalled.step(np.clip((obs['desired_goal'] - obs['achieved_goal']) / setup.ee_step, -1, 1))[0]
    q, goal = stalled._q.copy(), stalled._goal.copy()
    tip, jac = setup.place(q)
    a = np.clip((goal - tip) / setup.ee_step, -1, 1)
    a[:, 150:] = rng.uniform(-1, 1, (3, 50))                  # and actions that do not ask toward the goal
    target = setup.move(q, jac, a)
    state = np.where(np.arange(200) < 100, READY, rng.choice([READY, RECOVERING, RECOVERED], 200)).astype(np.int8)
    to = rng.uniform(setup.arm.lower, setup.arm.upper, (200, setup.arm.n)).T
    error = setup.task.error(tip.T, goal.T)
    best = np.where(rng.random(200) < 0.5, np.inf, error + rng.uniform(-0.01, 0.01, 200))
    since = rng.integers(0, setup.stall_steps + 1, 200).astype(np.int32)
    before = Recoveries(state, to, best, since, to.copy())
    batch, after = setup.recover(q, tip, target, a, goal, before)
    started = (after.state == RECOVERING) & (state == READY)
    assert started[:150].sum() > 0 and not started[150:].any()      # some were blocked or stalled; none at random
    assert ((after.since == 0) & (since > 0))[150:].any()            # a try that is none starts the count again
    for i in range(200):
        one, r = setup.recover_one(q[:, i].tolist(), tip[:, i].tolist(), target[:, i].tolist(), a[:, i].tolist(),
                                   goal[:, i].tolist(), Recovery(int(state[i]), tuple(to[:, i].tolist()),
                                                                 float(best[i]), int(since[i])))
        assert one == batch[:, i].tolist() and r.state == after.state[i], i
        if state[i] == READY:
            assert (r.best, r.since) == (after.best[i], after.since[i]), i
        if r.state != READY:
            assert r.q == tuple(after.q[:, i].tolist())
    for kwargs in (dict(start='random'), dict(start='chained', goal='pose')):
        n = 4
        recovering = lambda rec: int((rec.state == RECOVERING).sum())    # noqa: E731
        assert lockstep(n, 1, 160, recovering, model=UR5, reward_type='dense', **kwargs) > 0, kwargs


def test_a_small_step_a_limit_blocks_counts_and_an_arm_at_its_goal_is_left_alone():
    """A learned policy asks little near its goal (ARS's gain is a fraction of the P-controller's): a step that asks
    for a tenth of the way or more, which a joint limit blocks, starts the recovery even when it asks for less than
    RECOVERY_ASK of a full step (a KUKA KR210's ARS stalled so 5-13 cm short on 2 % of goals from random starts); one
    that asks for less does not, nor does an arm already at its goal, whatever it asks."""
    big = dict(model=XACRO_ARM, xacro_args='scale:=2.5')          # a 2.7 m arm: a full step is 0.14 m
    setup = ReachSetup(**big)
    stalled = ReachVectorEnv(300, start='random', limit_recovery=False, **big)
    obs = stalled.reset(seed=0)[0]
    for _ in range(30):
        obs = stalled.step(np.clip((obs['desired_goal'] - obs['achieved_goal']) / setup.ee_step, -1, 1))[0]
    q, goal = stalled._q.copy(), stalled._goal.copy()
    tip, jac = setup.place(q)
    error = setup.task.error(tip.T, goal.T)
    far = error > 2 * setup.task.distance_threshold               # stalled: most of them at a limit
    q, tip, jac = q[:, far], tip[:, far], jac[:, :, far]
    near = 1.4 * setup.task.distance_threshold                    # the same way, 7 cm: a small step's goal
    goal = tip + near * (goal[:, far] - tip) / error[far]
    m = q.shape[1]
    ready = Recoveries(np.zeros(m, dtype=np.int8), np.zeros_like(q), np.full(m, np.inf), np.zeros(m, np.int32),
                       np.zeros_like(q))

    def started(fraction: float, goals=goal) -> np.ndarray:
        a = fraction * (goals - tip) / setup.ee_step
        return setup.recover(q, tip, setup.move(q, jac, a), a, goals, ready)[1].state == RECOVERING

    assert m >= 10 and 0.2 * near < env.RECOVERY_ASK * setup.ee_step, m    # a fifth of the way is a small step
    assert started(0.2).sum() >= m // 4, (started(0.2).sum(), m)  # blocked at a limit, asked a fifth of the way
    assert not started(0.05).any()                                # asking less than a tenth of the way: no try
    inside = tip + 0.8 * (goal - tip) / 1.4                       # 4 cm: within the goal's 5, asking the whole way
    assert not started(1.0, inside).any()                         # at its goal: nothing to go round


def lockstep(n: int, seed: int, steps: int, count, policy=None, **kwargs) -> int:
    """gymnasium's SyncVectorEnv over n Reach-v0 envs of kwargs and ReachVectorEnv, reset with seed and driven by
    policy (the P-controller by default) for steps steps, equal bit for bit at every step: the sum over the steps of
    count(the vector env's Recoveries)."""
    sync, vec = make_sync(n, **kwargs), gymnasium.make_vec('robot_ai/Reach-v0', num_envs=n, **kwargs)
    o1, _ = sync.reset(seed=seed)
    assert_same(o1, vec.reset(seed=seed)[0])
    p = policy or learn.p_controller(vec.unwrapped.setup)
    total = 0
    for _ in range(steps):
        a = p.act_batch(ars.flatten_batch(vec.single_observation_space, o1)).astype(np.float32)
        r1, r2 = sync.step(a), vec.step(a)
        for x, y in zip(r1, r2):
            assert_same(x, y)
        o1 = r1[0]
        total += count(vec.unwrapped._recovery)
    return total


def test_through_the_layer_with_a_body_each_goal_is_planned_first_and_equal_to_sync_vector_env():
    """Through a safety layer with a body, each episode's goal is planned at its start (ReachSetup.first_way, as
    reach_controller plans a goal) and the arm follows the way before the policy moves it; ReachVectorEnv still
    equals SyncVectorEnv bit for bit (each OMPL search is seeded from its own problem). plan_first=False: the
    policy first; plan_first without a body is one line."""
    kwargs = dict(model=KUKA, obstacles=WORLD, velocity_scale=0.25, start='chained')
    assert lockstep(3, 5, 300, lambda rec: int(rec.planned().sum()), **kwargs) > 0
    first, policy = ReachEnv(**kwargs), ReachEnv(plan_first=False, **kwargs)
    assert first.setup.plans_first and not policy.setup.plans_first
    assert not ReachSetup(model=KUKA, obstacles=WORLD).plans_first          # in-process: the policy first
    planned = 0
    for seed in range(6):
        first.reset(seed=seed)
        policy.reset(seed=seed)
        planned += first._recovery.state == RECOVERING
        assert policy._recovery == Recovery()
    assert planned >= 4, planned
    joints = ReachEnv(control='joints', **kwargs)           # a joints policy's arm is planned for too: its goal
    joints.reset(seed=1)                                    # configurations are sought by the tip's steps
    assert joints._recovery.state == RECOVERING
    for _ in range(joints.setup.episode_steps):
        info = joints.step(np.zeros(joints.action_space.shape))[-1]
    assert info['is_success'] and not info['collision']     # the way alone, the policy asking nothing
    with pytest.raises(ReachError, match='plan_first plans round the arm'):
        ReachSetup(model=KUKA, plan_first=True)
    with pytest.raises(ReachError, match='plan_first must be true or false'):
        ReachSetup(model=KUKA, obstacles=WORLD, plan_first='yes')


def test_a_way_a_collision_holds_is_planned_again_from_there_as_the_node_does(monkeypatch):
    """A planned way on which a collision holds the arm is planned again from where it stands, at most MAX_REPLANS
    times an episode (reach_controller's rule), the vector env equal to SyncVectorEnv bit for bit meanwhile. The
    collision: a band of the first joint's range the arm may not enter, which the planner does not know of."""
    motion_hits = ReachSetup._motion_hits

    def banded(self, before_t, after_t, padding=0.0):
        inside = lambda x: (x[0] > 0.3) & (x[0] < 0.6)      # noqa: E731
        return motion_hits(self, before_t, after_t, padding) | (inside(after_t) & ~inside(before_t))
    monkeypatch.setattr(ReachSetup, '_motion_hits', banded)
    replans = []
    kwargs = dict(model=KUKA, obstacles=WORLD, velocity_scale=0.25, start='random')
    lockstep(6, 3, 200, lambda rec: 0, **kwargs)
    vec = ReachVectorEnv(6, **kwargs)
    obs = vec.reset(seed=3)[0]
    p = learn.p_controller(vec.setup)
    for _ in range(200):
        obs = vec.step(p.act_batch(ars.flatten_batch(vec.single_observation_space, obs)).astype(np.float32))[0]
        replans.append(vec._replans.copy())
    assert (replans[-1] == env.MAX_REPLANS).any(), replans[-1]      # held each time on the band: 3, then the policy
    assert (np.diff(np.array(replans), axis=0) >= 0).all() and replans[-1].max() <= env.MAX_REPLANS


class Down:
    """A policy that drives the tip straight down, into the table, whatever the goal."""

    def act_batch(self, x: np.ndarray) -> np.ndarray:
        return np.tile([0.0, 0.0, -1.0], (len(x), 1))


def test_a_policy_a_collision_holds_short_of_the_goal_gets_a_way_planned_again():
    """The policy's arm (after its way, or with none) that a collision holds short of the goal gets a way planned
    again from where it stands, as one held on its way does: MAX_REPLANS tries a goal, counted whether a way is found
    or not (reach_controller's rule: ReachSetup.replanning). Not where the tip is at the goal, nor where the setup
    does not plan first. The vector env equals SyncVectorEnv bit for bit meanwhile."""
    kwargs = dict(model=KUKA, obstacles=WORLD, velocity_scale=0.25, start='random')
    lockstep(4, 7, 200, lambda rec: 0, policy=Down(), **kwargs)
    setup = ReachSetup(**kwargs)
    goal = setup.goals_of(setup.arm.home[:, None])
    tips = np.hstack((goal, goal, goal + [[0.2], [0.0], [0.0]]))
    assert setup.replanning([True, False, False], tips, np.repeat(goal, 3, axis=1)).tolist() == [True, False, True]
    for plan_first, most in ((True, env.MAX_REPLANS), (False, 0)):
        vec = ReachVectorEnv(6, plan_first=plan_first, **kwargs)
        vec.reset(seed=11)
        counts, held = [], np.zeros(6, dtype=bool)
        for _ in range(300):
            info = vec.step(np.tile([0.0, 0.0, -1.0], (6, 1)))[-1]
            held |= info.get('collision', np.zeros(6, dtype=bool))
            counts.append(vec._replans.copy())
        assert held.any()
        assert (np.diff(np.array(counts), axis=0) >= 0).all() and counts[-1].max() == most, counts[-1]
        assert (counts[-1][~held] == 0).all()


def test_the_setting_is_kept_by_policy_files_and_older_files_learned_without_it(tmp_path):
    """A new file keeps limit_recovery (true); a file from before the recovery has none and acts without it, as it
    learned; joints control has none; a setting that is not a bool is one line."""
    training = learn.train(dict(model=UR5), replace(learn.SETTINGS, iterations=3), seed=0, evaluate_episodes=50)
    path = policy_files.save(training, str(tmp_path / 'reach.npz'))
    _, setup, _ = policy_files.load(path)
    assert setup.limit_recovery and training.env_kwargs['limit_recovery'] is True
    old = dict(training.env_kwargs)
    del old['limit_recovery']
    assert not policy_files._setup_of_kwargs(old, {}).limit_recovery
    assert not ReachSetup(model=UR5, control='joints').limit_recovery
    with pytest.raises(ReachError, match='limit_recovery must be true or false'):
        ReachSetup(model=UR5, limit_recovery='yes')


def test_in_a_world_the_recovery_goes_round_the_obstacles_on_a_way_it_checked():
    """The KUKA among test/world.yaml's table and two boxes, the P-controller from 300 random starts: a collision
    holds the arm (a motion that would touch is not made), which stalls, and the recovery takes it to a reaching
    configuration clear of contacts on a way checked step by step, through a via point where the straight way
    touches. At least 97 % reached (without the recovery under 80 %); of the steps the recovery made, almost none
    refused by a collision; some ways went through a via point, and every such way's points are clear; the vector
    env equals single envs while they go round."""
    setup = ReachSetup(model=KUKA, obstacles=WORLD, start='random')
    plain = ReachSetup(model=KUKA, obstacles=WORLD, start='random', limit_recovery=False)
    without = learn.evaluate(learn.p_controller(plain), plain, 300)
    p = learn.p_controller(setup)
    env = ReachVectorEnv(300, setup=setup)
    obs, _ = env.reset(seed=2 ** 31)
    recovering = refused = 0
    vias = []
    for _ in range(env.max_episode_steps):
        rec = env._recovery
        going = rec.state == RECOVERING
        onward = going & (rec.then != rec.q).any(axis=0)
        vias += [(rec.q[:, i].copy(), rec.then[:, i].copy()) for i in np.flatnonzero(onward)]
        obs, _, _, _, infos = env.step(p.act_batch(ars.flatten_batch(env.single_observation_space, obs)))
        recovering += int(going.sum())
        refused += int((going & infos['collision']).sum())
        assert not setup.body.in_collision(env._q.T).any()
    rate = infos['is_success'].mean()
    assert rate >= 0.97 and without.success_rate < 0.8, (rate, without)
    assert recovering > 100 and refused < 0.02 * recovering, (recovering, refused)
    assert vias and not setup.body.in_collision(np.array([v for pair in vias for v in pair])).any()
    via = lambda rec: int(((rec.state == RECOVERING) & (rec.then != rec.q).any(axis=0)).sum())    # noqa: E731
    assert lockstep(12, 40, 100, via, model=KUKA, obstacles=WORLD, start='random') > 0
    # through a safety layer (reach_controller's prediction of its arm) the ways keep the layer's margin
    moving = setup.through(Limits.of(setup.arm, velocity_scale=0.5), margin=0.03)
    rng = np.random.default_rng(9)
    q, goals = [], []
    while len(q) < 40:
        a, b = rng.uniform(setup.arm.lower, setup.arm.upper, (2, setup.arm.n))
        if not setup.body.in_collision(np.array([a, b]), 0.03).any():
            q.append(a)
            goals.append(b)
    goals = setup.goals_of(np.array(goals).T)
    via, to = moving.recovery_way(goals, np.array(q).T)
    clear = ~setup.body.in_collision(to.T, 0.03) & ~setup.body.in_collision(via.T, 0.03)
    assert clear.mean() > 0.9 and setup.task.is_success(setup.goals_of(to[:, clear]).T, goals[:, clear].T).all()
    assert moving.way_margin == 0.03 and setup.way_margin == 0.0


def test_ars_trained_from_home_reaches_from_random_starts_and_chained():
    """ARS as train makes it (its rollouts without the recovery), evaluated with it: at least 99 % from home, from
    random starts and chained on the UR5 (300 goals each)."""
    training = learn.train(dict(model=UR5), seed=0, evaluate_episodes=300)
    for start in ('home', 'random', 'chained'):
        e = learn.evaluate(training.policy, training.setup, 300, start=start)
        assert e.success_rate >= 0.99, (start, e)


def test_a_goal_inside_an_obstacle_is_neither_drawn_nor_taken_as_reach_controller_refuses_it():
    """Issue 57: Reach-v0 took a goal inside the table (a reset option) that reach_controller ignores; the two agree
    now, and no drawn goal is inside an obstacle either (its configuration was clear, a TCP tip need not be)."""
    e = gymnasium.make('robot_ai/Reach-v0', model=KUKA, obstacles=WORLD)
    setup = e.unwrapped.setup
    with pytest.raises(ReachError, match=r'inside table: no tip reaches it'):
        e.reset(seed=0, options={'goal': [0.3, 0.2, -0.03]})
    obs, _ = e.reset(seed=0, options={'goal': [0.3, 0.2, 0.3]})            # beside it: taken
    assert obs['desired_goal'].tolist() == [0.3, 0.2, 0.3]
    for seed in range(300):
        obs, _ = e.reset(seed=seed)
        assert setup.obstacle_holding(obs['desired_goal']) is None, (seed, obs['desired_goal'])
    e.close()
