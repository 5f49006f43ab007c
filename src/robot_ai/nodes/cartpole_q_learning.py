"""cartpole_q_learning: the course's Q-learning agent with RBF features served over ROS, many learners at once.

ROS Parameters
    ~env_id (str), ~episodes (int), ~gamma (float), ~regressor (str), ~components (int), ~learners (int): what
        zero or empty request fields mean; unset, zero or empty: q_learning.DEFAULTS (CartPole-v0, 500, 0.99,
        tf, 1000, 1).
    ~output_dir (str, "" = $ROS_HOME/robot_ai): where plots, videos, policy files and CSV logs are written;
        requests never name paths.
    ~policy (str, ""): a Q-learning policy file (.npz) loaded at start as the node's agent; a bad file ends the
        node with one line.
    ~ray_address (str, ""): every learner of a training a task on this Ray cluster (HOST:PORT of its head, or auto;
        docs/fleet.md) instead of the node's own processes, with the same numbers; a learner's episodes are then
        reported when it ends. Ray missing or no cluster there: the node ends with one line.

ROS Services
    ~train (robot_ai/QLearning): train; when it ends, every learner's greedy agent plays 100 greedy episodes
        (start states from the training's seed), the best (greedy average, then last-100 average) is saved as a
        policy file, and becomes the node's agent if it does at least as well as the current agent on those
        same episodes. Learners run in worker processes (q_learning.train): a learner whose process dies or hangs
        is named in the message and the log, and the others' results come back.
    ~evaluate (robot_ai/EvaluateAgent): greedy episodes of the agent, one call at a time (later calls wait).
    ~act (robot_ai/Act): the agent's greedy action for one state.
    ~load_policy (robot_ai/LoadPolicy): load a Q-learning policy file as the agent; a bad file changes nothing.
    Every ~act and ~evaluate answer says whose agent it used: which training and learner, or which file.

ROS Actions
    ~training (robot_ai/QLearningAction): the same training as a preemptable goal, feedback per episode of every
        learner; a cancelled goal returns the learners that had finished.

ROS Publishers
    ~progress (robot_ai/QLearningProgress): after every episode of every learner of a running training.

Bad requests get success: false and a message that says what is allowed, at once; the node keeps serving.
Trainings run one at a time; later requests wait their turn. A response arrives before its plot: plot_path
names the file being drawn (see agent_common).
"""
import threading
import time
from dataclasses import dataclass

import actionlib
import numpy as np
import rospy

from robot_ai import policies

from robot_ai.cartpole import outputs, q_learning
from robot_ai.cartpole.dynamics import CartPoleDynamics, RequestError
from robot_ai.cartpole.q_learning import Agent
from robot_ai.msg import QLearningAction, QLearningFeedback, QLearningProgress, QLearningResult
from robot_ai.nodes.agent_common import (CancelledRun, PlotProcess, agent_settings, answer, answer_goal, answer_load,
                                         load_of_kind, policy_param, stopping, write_files)
from robot_ai.nodes.params import run_node
from robot_ai.srv import (Act, ActResponse, EvaluateAgent, EvaluateAgentResponse, LoadPolicy, QLearning,
                          QLearningResponse)

EVALUATE_EPISODES = 100


@dataclass(frozen=True)
class ServedAgent:
    """The node's agent, the env it was trained on, and whose it is."""
    agent: Agent
    env_id: str
    origin: str


class CartPoleQLearningNode:

    def __init__(self):
        self.defaults, self.output_dir = agent_settings(q_learning, 'trainings')
        self.ray_address = str(rospy.get_param('~ray_address', '') or '')
        if self.ray_address:
            from robot_ai import fleet
            try:
                fleet.connect(self.ray_address)
            except fleet.FleetError as e:
                raise ValueError(f'~ray_address: {e}') from None
        self.served: ServedAgent | None = None
        loaded = policy_param(Agent.kind)
        if loaded is not None:
            self._install(loaded)
        self.trainings = 0
        self.train_lock = threading.Lock()  # one training at a time; later requests wait their turn
        self.evaluate_lock = threading.Lock()  # one evaluation at a time: memory stays bounded (see MAX_EVAL_EPISODES)
        self.plots = PlotProcess()
        self.progress_pub = rospy.Publisher('~progress', QLearningProgress, queue_size=1000)
        self.services = [rospy.Service('~train', QLearning, self._on_train),
                         rospy.Service('~evaluate', EvaluateAgent, self._on_evaluate),
                         rospy.Service('~act', Act, self._on_act),
                         rospy.Service('~load_policy', LoadPolicy, self._on_load_policy)]
        self.action = actionlib.SimpleActionServer('~training', QLearningAction, self._on_goal, auto_start=False)
        self.action.start()
        rospy.loginfo(f'cartpole_q_learning ready: defaults {self.defaults}, artifacts in {self.output_dir}')

    # ------------------------------------------------------------------------------------- the training
    def _train(self, req, feedback=None, should_stop=None):
        """Train as a QLearning request or goal says; return (the response's fields or None if cancelled, result)."""
        start = None
        if req.initial_policy:
            try:
                start = load_of_kind(req.initial_policy, Agent.kind)
            except policies.PolicyError as e:
                raise RequestError(f'initial_policy: {e}')
        training = q_learning.resolve(req.env_id, req.episodes, req.gamma, req.regressor, req.components,
                                      req.learners, req.bootstrap_at_time_limit, self.defaults,
                                      start=start.actor if start else None,
                                      start_settings=start.metadata['settings'] if start else None,
                                      started_from=start.path if start else '')
        n, k = training.episodes, training.learners
        recent = [[] for _ in range(k)]     # the last 100 totals of each learner, for the running averages
        done = [0]

        def progress(learner, episode, total, eps):
            window = recent[learner]
            window.append(total)
            del window[:-100]
            average = sum(window) / len(window)
            elapsed = time.time() - t0
            done[0] += episode == n
            self.progress_pub.publish(QLearningProgress(learner=learner, episode=episode, episodes=n,
                                                        total_reward=total, running_average=average,
                                                        epsilon=eps, elapsed=elapsed))
            if feedback is not None:
                feedback(QLearningFeedback(learner=learner, episode=episode, episodes=n, total_reward=total,
                                           running_average=average, epsilon=eps, learners_done=done[0],
                                           elapsed=elapsed))
            rospy.loginfo_throttle(2.0, f'training: {done[0]} of {k} learners done; learner {learner} episode '
                                        f'{episode}/{n}, running average {average:.1f}')

        with self.train_lock:
            t0 = time.time()
            result = q_learning.train(training, req.seed, progress=progress, ray_address=self.ray_address,
                                      should_stop=lambda: stopping() or bool(should_stop and should_stop()))
            for j, why in result.failed.items():
                rospy.logerr(f'training: learner {j} (seed {req.seed + j}) failed: {why}')
            if result.cancelled:
                return None, self._cancelled(result, training, req, time.time() - t0)
            self.trainings += 1
            number, env_id = self.trainings, training.dynamics.env_id
            best = result.best_learner()
            agent, figures = result.agents[best], result.figures_of(best)
            kept = self._keep_better(agent, training, req.seed, number, best, figures)
            video = None if not req.record_video else (lambda path: outputs.record_video(
                env_id, agent.act, training.max_steps, req.seed + best, path)[0])
            files = write_files(
                self.plots, self.output_dir, 'qlearning', env_id, req.seed, outputs.q_learning_plot_job(result),
                policy=lambda path: policies.save(path, agent, env_id, req.seed + best, training.settings(), figures,
                                                  f'training {number} of cartpole_q_learning, learner {best}'
                                                  + training.origin()),
                log=outputs.q_learning_log(result), video=video)
            elapsed = time.time() - t0
        failures = ''.join(f'; learner {j} (seed {req.seed + j}) failed: {why}' for j, why in result.failed.items())
        collapsed = q_learning.collapse_note(result)
        collapsed = f'; {collapsed}' if collapsed else ''
        message = (f'{q_learning.summary(result)}{failures}; best learner {best} (seed {req.seed + best}): greedy '
                   f'average {figures["greedy_average"]:.1f} over {q_learning.GREEDY_EPISODES} episodes{collapsed}; '
                   f'{kept}; '
                   f'{files.note}')
        rospy.loginfo(message)
        return dict(success=True, message=message, total_rewards=list(result.total_rewards[0]),
                    last100_averages=list(result.last100_averages), learner_seeds=result.learner_seeds,
                    best_learner=best, best_greedy_average=figures['greedy_average'],
                    mean_last100=result.mean_last100, ci95_last100=result.ci95_last100, elapsed=elapsed,
                    **files.fields()), result

    def _cancelled(self, result, training, req, elapsed: float) -> CancelledRun:
        """A cancelled training keeps the best of its finished learners as a policy file, and every episode played
        as a CSV log (and their plot); the file's source says it was cancelled."""
        if not result.finished:
            return CancelledRun(result, elapsed)
        env_id, best = training.dynamics.env_id, result.best_learner()
        agent, figures = result.agents[best], result.figures_of(best)
        source = (f'a training of cartpole_q_learning cancelled with {len(result.finished)} of {training.learners} '
                  f'learners finished, learner {best}')
        files = write_files(
            self.plots, self.output_dir, 'qlearning', env_id, req.seed, outputs.q_learning_plot_job(result),
            policy=lambda path: policies.save(path, agent, env_id, req.seed + best, training.settings(), figures,
                                              source),
            log=outputs.q_learning_log(result))
        return CancelledRun(result, elapsed, files)

    def _keep_better(self, agent: Agent, training, seed: int, number: int, learner: int, figures: dict) -> str:
        """The training's best learner becomes the node's agent if its greedy average is at least the current
        agent's on the same greedy episodes (the training's env, start states from the learner's seed)."""
        origin = (f'training {number}, learner {learner} (seed {seed + learner}, {training.dynamics.env_id}, greedy '
                  f'average {figures["greedy_average"]:.1f}, last-100 average {figures["last100_average"]:.1f})')
        current = self.served
        if current is not None:
            theirs = q_learning.greedy_average(current.agent, training, seed + learner)
            if figures['greedy_average'] < theirs:
                return (f'the node keeps its agent from {current.origin}, whose greedy average on the same '
                        f'episodes is {theirs:.1f}')
        self.served = ServedAgent(agent, training.dynamics.env_id, origin)
        return 'it is now the node\'s agent'

    def _install(self, policy: policies.Policy) -> str:
        source = f', {policy.metadata["source"]}' if policy.metadata['source'] else ''
        self.served = ServedAgent(policy.actor, policy.env_id,
                                  f'the file {policy.path} ({policy.env_id}, seed {policy.seed}{source})')
        return f'the node\'s agent is now {self.served.origin}'

    # ------------------------------------------------------------------------------------- handlers
    def _on_train(self, req):
        return answer(lambda: self._train(req), QLearningResponse, 'training')

    def _on_goal(self, goal):
        def cancelled(run: CancelledRun):
            result = run.result
            seeds = ', '.join(str(s) for s in result.learner_seeds)
            which = (f'learners {", ".join(str(j) for j in result.finished)} (seeds {seeds}) had finished'
                     if result.finished else 'no learner had finished')
            return (f'cancelled: {which}, {len(result.finished)} of {result.training.learners}{run.note()}',
                    dict(total_rewards=list(result.total_rewards[0]) if result.total_rewards else [],
                         last100_averages=list(result.last100_averages), learner_seeds=result.learner_seeds,
                         best_learner=-1, mean_last100=result.mean_last100, ci95_last100=result.ci95_last100,
                         **run.fields()))
        answer_goal(self.action, lambda: self._train(goal, self.action.publish_feedback,
                                                     self.action.is_preempt_requested),
                    QLearningResult, 'training', cancelled)

    def _on_evaluate(self, req):
        try:
            served = self.served
            if served is None:
                raise RequestError('no agent yet: train one first (~train or ~training) or load a policy file')
            dynamics = CartPoleDynamics.of(req.env_id or served.env_id)
            episodes = int(req.episodes or EVALUATE_EPISODES)
            max_steps = dynamics.resolve_max_steps(req.max_steps)
            if not 1 <= episodes <= q_learning.MAX_EVAL_EPISODES:
                raise RequestError(f'episodes must be 1 to {q_learning.MAX_EVAL_EPISODES} (0 = {EVALUATE_EPISODES}), '
                                   f'got {episodes}')
            with self.evaluate_lock:
                lengths = served.agent.evaluate(dynamics, episodes, max_steps, req.seed)
            return EvaluateAgentResponse(success=True, message=f'{episodes} greedy episodes of {dynamics.env_id} with '
                                         f'the agent from {served.origin}',
                                         lengths=[int(v) for v in lengths], avg_length=float(np.mean(lengths)))
        except RequestError as e:
            return EvaluateAgentResponse(success=False, message=str(e))

    def _on_act(self, req):
        served = self.served
        if served is None:
            return ActResponse(success=False, message='no agent yet: train one first or load a policy file', action=-1)
        try:
            return ActResponse(success=True, message=f'the agent from {served.origin}',
                               action=served.agent.act(req.state))
        except RequestError as e:
            return ActResponse(success=False, message=str(e), action=-1)

    def _on_load_policy(self, req):
        return answer_load(req.path, Agent.kind, self._install)


def main():
    run_node('cartpole_q_learning', CartPoleQLearningNode)
