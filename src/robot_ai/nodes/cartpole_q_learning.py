"""cartpole_q_learning: the course's Q-learning agent with RBF features served over ROS, many learners at once.

ROS Parameters
    ~env_id (str), ~episodes (int), ~gamma (float), ~regressor (str), ~components (int), ~learners (int): what
        zero or empty request fields mean; unset, zero or empty: q_learning.DEFAULTS (CartPole-v0, 500, 0.99,
        tf, 1000, 1).
    ~output_dir (str, "" = $ROS_HOME/robot_ai): where plots and videos are written; requests never name paths.

ROS Services
    ~train (robot_ai/QLearning): train; learner 0 of the latest successful training becomes the agent.
    ~evaluate (robot_ai/EvaluateAgent): greedy episodes of the agent.
    ~act (robot_ai/Act): the agent's greedy action for one state.

ROS Actions
    ~training (robot_ai/QLearningAction): the same training as a preemptable goal, feedback per episode of
        learner 0.

ROS Publishers
    ~progress (robot_ai/QLearningProgress): after every episode of every learner of a running training.

Bad requests get success: false and a message that says what is allowed, at once; the node keeps serving.
Trainings run one at a time; later requests wait their turn. A response arrives before its plot: plot_path
names the file being drawn (see agent_common).
"""
import threading
import time

import actionlib
import numpy as np
import rospy

from robot_ai.cartpole import artifacts, q_learning
from robot_ai.cartpole.dynamics import CartPoleDynamics, RequestError
from robot_ai.msg import QLearningAction, QLearningFeedback, QLearningProgress, QLearningResult
from robot_ai.nodes.agent_common import PlotProcess, agent_settings, answer, answer_goal, write_files
from robot_ai.srv import Act, ActResponse, EvaluateAgent, EvaluateAgentResponse, QLearning, QLearningResponse

EVALUATE_EPISODES = 100


class CartPoleQLearningNode(object):

    def __init__(self):
        self.defaults, self.output_dir = agent_settings(q_learning, 'trainings')
        self.agent, self.agent_env = None, None
        self.train_lock = threading.Lock()  # one training at a time; later requests wait their turn
        self.plots = PlotProcess()
        self.progress_pub = rospy.Publisher('~progress', QLearningProgress, queue_size=1000)
        self.services = [rospy.Service('~train', QLearning, self._on_train),
                         rospy.Service('~evaluate', EvaluateAgent, self._on_evaluate),
                         rospy.Service('~act', Act, self._on_act)]
        self.action = actionlib.SimpleActionServer('~training', QLearningAction, self._on_goal, auto_start=False)
        self.action.start()
        rospy.loginfo('cartpole_q_learning ready: defaults %s, artifacts in %s', self.defaults, self.output_dir)

    # ------------------------------------------------------------------------------------- the training
    def _train(self, req, feedback=None, should_stop=None):
        """Train as a QLearning request or goal says; return (the response's fields or None if cancelled, result)."""
        training = q_learning.resolve(req.env_id, req.episodes, req.gamma, req.regressor, req.components,
                                      req.learners, req.bootstrap_at_time_limit, self.defaults)
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
            if learner == 0 and feedback is not None:
                feedback(QLearningFeedback(episode=episode, episodes=n, total_reward=total, running_average=average,
                                           epsilon=eps, learners_done=done[0], elapsed=elapsed))
            if learner == 0:
                rospy.loginfo_throttle(2.0, 'training: learner 0 episode %d/%d, running average %.1f'
                                       % (episode, n, average))

        with self.train_lock:
            t0 = time.time()
            result = q_learning.train(training, req.seed, progress=progress,
                                      should_stop=lambda: rospy.is_shutdown() or bool(should_stop and should_stop()))
            if result.cancelled:
                return None, result
            env_id = training.dynamics.env_id
            self.agent, self.agent_env = result.agent, env_id
            video = None if not req.record_video else (lambda path: artifacts.record_video(
                env_id, result.agent.act, training.max_steps, req.seed, path)[0])
            plot_path, video_path, files = write_files(self.plots, self.output_dir, 'qlearning', env_id, req.seed,
                                                       artifacts.q_learning_plot_job(result), video)
            elapsed = time.time() - t0
        message = '%s; %s' % (q_learning.summary(result), files)
        rospy.loginfo(message)
        return dict(success=True, message=message, total_rewards=list(result.total_rewards[0]),
                    last100_averages=list(result.last100_averages), mean_last100=result.mean_last100,
                    ci95_last100=result.ci95_last100, plot_path=plot_path, video_path=video_path,
                    elapsed=elapsed), result

    # ------------------------------------------------------------------------------------- handlers
    def _on_train(self, req):
        return answer(lambda: self._train(req), QLearningResponse, 'training')

    def _on_goal(self, goal):
        def cancelled(result):
            rewards = list(result.total_rewards[0]) if result.total_rewards else []
            return ('cancelled after %d of %d episodes of learner 0' % (len(rewards), result.training.episodes),
                    dict(total_rewards=rewards))
        answer_goal(self.action, lambda: self._train(goal, self.action.publish_feedback,
                                                     self.action.is_preempt_requested),
                    QLearningResult, 'training', cancelled)

    def _on_evaluate(self, req):
        try:
            agent, env_id = self.agent, self.agent_env
            if agent is None:
                raise RequestError('no agent yet: train one first (~train or ~training)')
            dynamics = CartPoleDynamics.of(req.env_id or env_id)
            episodes = int(req.episodes or EVALUATE_EPISODES)
            max_steps = dynamics.resolve_max_steps(req.max_steps)
            if not 1 <= episodes <= q_learning.MAX_EVAL_EPISODES:
                raise RequestError('episodes must be 1 to %d (0 = %d), got %d' % (
                    q_learning.MAX_EVAL_EPISODES, EVALUATE_EPISODES, episodes))
            lengths = agent.evaluate(dynamics, episodes, max_steps, req.seed)
            return EvaluateAgentResponse(success=True, message='%d greedy episodes of %s' % (episodes, dynamics.env_id),
                                         lengths=[int(v) for v in lengths], avg_length=float(np.mean(lengths)))
        except RequestError as e:
            return EvaluateAgentResponse(success=False, message=str(e))

    def _on_act(self, req):
        if self.agent is None:
            return ActResponse(success=False, message='no agent yet: train one first', action=-1)
        try:
            return ActResponse(success=True, message='', action=self.agent.act(req.state))
        except RequestError as e:
            return ActResponse(success=False, message=str(e), action=-1)


def main():
    rospy.init_node('cartpole_q_learning')
    try:
        CartPoleQLearningNode()
    except (RequestError, ValueError) as e:
        rospy.logfatal('cartpole_q_learning: bad parameter: %s', e)
        raise SystemExit(1)
    rospy.spin()
