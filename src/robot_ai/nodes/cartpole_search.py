"""cartpole_search: the course's CartPole random search served over ROS.

ROS Parameters
    ~env_id (str), ~iterations (int), ~episodes (int), ~final_episodes (int): what zero or empty request
        fields mean; unset, zero or empty: linear_search.DEFAULTS (CartPole-v1, 100, 100, 100).
    ~output_dir (str, "" = $ROS_HOME/robot_ai): where plots, videos, policy files and CSV logs are written;
        requests never name paths.
    ~policy (str, ""): a linear policy file (.npz) loaded at start as the node's policy; a bad file ends the node
        with one line.

ROS Services
    ~random_search (robot_ai/RandomSearch): run a search; it writes its best weights as a policy file and every
        candidate in a CSV log. Its best becomes the node's policy if its final average is at least the current
        policy's (so a small test search does not replace a good policy).
    ~evaluate (robot_ai/EvaluatePolicy): play episodes with given weights (empty: the node's policy).
    ~act (robot_ai/Act): the node's policy's action for one state.
    ~load_policy (robot_ai/LoadPolicy): load a linear policy file as the node's policy; a bad file changes nothing.
    Every response that uses the node's policy says whose it is: which search, or which file.

ROS Actions
    ~search (robot_ai/RandomSearchAction): the same search as a preemptable goal, feedback per candidate; a
        cancelled goal returns the best weights and the averages so far.

ROS Publishers
    ~progress (robot_ai/SearchProgress): after every candidate of any running search.

Bad requests get success: false and a message that says what is allowed; the node keeps serving.
A response arrives before its plot: plot_path names the file being drawn (see agent_common).
"""
import threading
import time
from dataclasses import dataclass

import actionlib
import numpy as np
import rospy

from robot_ai import policies

from robot_ai.cartpole import linear_search, outputs
from robot_ai.cartpole.dynamics import CartPoleDynamics, RequestError
from robot_ai.cartpole.linear_search import LinearPolicy
from robot_ai.msg import RandomSearchAction, RandomSearchFeedback, RandomSearchResult, SearchProgress
from robot_ai.nodes.agent_common import (CancelledRun, PlotProcess, agent_settings, answer, answer_goal, answer_load,
                                         policy_param, stopping, write_files)
from robot_ai.nodes.params import run_node
from robot_ai.srv import (Act, ActResponse, EvaluatePolicy, EvaluatePolicyResponse, LoadPolicy, RandomSearch,
                          RandomSearchResponse)
from robot_ai.text import counted


@dataclass(frozen=True)
class ServedPolicy:
    """The node's policy: its weights, the final average that ranks it, and whose it is."""
    weights: np.ndarray
    final: float
    origin: str


class CartPoleSearchNode:

    def __init__(self):
        self.defaults, self.output_dir = agent_settings(linear_search, 'searches')
        self.policy: ServedPolicy | None = None   # the best policy of any search so far, or a loaded file
        loaded = policy_param(LinearPolicy.kind)
        if loaded is not None:
            self._install(loaded)
        self.searches = 0
        self.search_lock = threading.Lock()  # one search at a time; later requests wait their turn
        self.plots = PlotProcess()
        self.progress_pub = rospy.Publisher('~progress', SearchProgress, queue_size=100)
        self.services = [rospy.Service('~random_search', RandomSearch, self._on_random_search),
                         rospy.Service('~evaluate', EvaluatePolicy, self._on_evaluate),
                         rospy.Service('~act', Act, self._on_act),
                         rospy.Service('~load_policy', LoadPolicy, self._on_load_policy)]
        self.action = actionlib.SimpleActionServer('~search', RandomSearchAction, self._on_goal, auto_start=False)
        self.action.start()
        rospy.loginfo(f'cartpole_search ready: defaults {self.defaults}, artifacts in {self.output_dir}')

    # ------------------------------------------------------------------------------------- the search
    def _search(self, req, feedback=None, should_stop=None):
        """Run the search of a RandomSearch request or goal; return (the response's fields or None if cancelled,
        result)."""
        search = linear_search.resolve(req.env_id, req.iterations, req.episodes, req.max_steps,
                                       req.final_episodes, self.defaults)
        env_id, iterations = search.dynamics.env_id, search.iterations

        def progress(i, avg, best, elapsed):
            self.progress_pub.publish(SearchProgress(iteration=i, iterations=iterations, last_avg_length=avg,
                                                     best_avg_length=best, elapsed=elapsed))
            if feedback is not None:
                feedback(i, iterations, best, elapsed)
            rospy.loginfo_throttle(2.0, f'search: candidate {i}/{iterations}, best average {best:.1f}')

        with self.search_lock:
            t0 = time.time()
            result = linear_search.random_search(search.dynamics, iterations, search.episodes, search.max_steps,
                                                 req.seed, search.final_episodes, progress=progress,
                                                 should_stop=lambda: stopping() or bool(
                                                     should_stop and should_stop()))
            if result.cancelled:
                return None, self._cancelled(result, req, env_id, time.time() - t0)
            self.searches += 1
            number = self.searches
            kept = self._keep_better(result, number)
            weights = result.best_weights
            video = None if not req.record_video else (lambda path: outputs.record_video(
                env_id, lambda obs: linear_search.act(weights, obs), search.max_steps, req.seed, path)[0])
            files = write_files(
                self.plots, self.output_dir, 'search', env_id, req.seed, outputs.search_plot_job(result),
                policy=lambda path: policies.save(path, LinearPolicy(weights), env_id, req.seed, result.settings(),
                                                  result.figures(), f'search {number} of cartpole_search'),
                log=outputs.search_log(result), video=video)
            elapsed = time.time() - t0
        message = (f'best average {result.best_avg_length:.1f} of {counted(iterations, "candidate")} x '
                   f'{counted(search.episodes, "episode")} ({env_id}, seed {req.seed}); final '
                   f'{result.final_avg_length:.1f} over {counted(search.final_episodes, "episode")}; {kept}; '
                   f'{files.note}')
        rospy.loginfo(message)
        return dict(success=True, message=message, best_weights=list(result.best_weights),
                    best_avg_length=result.best_avg_length, avg_lengths=list(result.avg_lengths),
                    final_avg_length=result.final_avg_length, elapsed=elapsed, **files.fields()), result

    def _cancelled(self, result, req, env_id: str, elapsed: float) -> CancelledRun:
        """A cancelled search keeps its best so far as a policy file and its candidates as a CSV log (and their
        plot); the file's source says it was cancelled, its figures have no final evaluation."""
        if not len(result.avg_lengths):
            return CancelledRun(result, elapsed)
        weights = result.best_weights
        figures = {k: v for k, v in result.figures().items() if k != 'final_avg_length'}
        source = (f'a search of cartpole_search cancelled after {len(result.avg_lengths)} of {result.iterations} '
                  'candidates (its best so far)')
        files = write_files(
            self.plots, self.output_dir, 'search', env_id, req.seed, outputs.search_plot_job(result),
            policy=lambda path: policies.save(path, LinearPolicy(weights), env_id, req.seed, result.settings(),
                                              figures, source),
            log=outputs.search_log(result))
        return CancelledRun(result, elapsed, files)

    def _keep_better(self, result, number: int) -> str:
        """Make the search's best the node's policy if its final average is at least the current policy's."""
        origin = (f'search {number} ({result.env_id}, seed {result.seed}, {result.iterations} x {result.episodes}, '
                  f'final {result.final_avg_length:.1f})')
        if self.policy is not None and result.final_avg_length < self.policy.final:
            return f'the node keeps its policy from {self.policy.origin}'
        self.policy = ServedPolicy(result.best_weights.copy(), result.final_avg_length, origin)
        return 'its best is now the node\'s policy'

    def _install(self, policy: policies.Policy) -> str:
        """A loaded file becomes the node's policy; later searches replace it if their final average is at least
        the file's, as this node measures it (~final_episodes episodes of the file's env, seed 0): a file's own
        claims are never what a search is compared with."""
        dynamics = CartPoleDynamics.of(policy.env_id)
        episodes = int(self.defaults.get('final_episodes') or linear_search.DEFAULTS['final_episodes'])
        final = float(policy.evaluate(dynamics, episodes, dynamics.max_episode_steps, 0).mean())
        claimed = policy.metadata['figures'].get('final_avg_length')
        claim = f', the file says {claimed:.1f}' if isinstance(claimed, (int, float)) and claimed != final else ''
        self.policy = ServedPolicy(policy.actor.weights.copy(), final, f'the file {policy.path}'
                                   f' ({policy.env_id}, seed {policy.seed}, final {final:.1f} over {episodes} episodes '
                                   f'measured on loading{claim})')
        return f'the node\'s policy is now {self.policy.origin}'

    # ------------------------------------------------------------------------------------- handlers
    def _on_random_search(self, req):
        return answer(lambda: self._search(req), RandomSearchResponse, 'search')

    def _on_goal(self, goal):
        def feedback(i, n, best, elapsed):
            self.action.publish_feedback(RandomSearchFeedback(iteration=i, iterations=n, best_avg_length=best,
                                                              elapsed=elapsed))

        def cancelled(run: CancelledRun):
            result = run.result
            avgs = result.avg_lengths
            best = f'; best so far: candidate {result.best_index + 1}, average {result.best_avg_length:.1f}' \
                if len(avgs) else ''
            return (f'cancelled after {len(avgs)} of {counted(result.iterations, "candidate")}{best}{run.note()}',
                    dict(avg_lengths=list(avgs), best_avg_length=result.best_avg_length,
                         best_weights=list(result.best_weights) if len(avgs) else [], **run.fields()))
        answer_goal(self.action, lambda: self._search(goal, feedback, self.action.is_preempt_requested),
                    RandomSearchResult, 'search', cancelled)

    def _on_evaluate(self, req):
        try:
            policy = self.policy
            if len(req.weights) == 0:
                if policy is None:
                    raise RequestError('no policy yet: run a search, load a policy file, or give 4 weights')
                weights, whose = policy.weights, f'the node\'s policy, from {policy.origin}'
            else:
                weights, whose = linear_search.check_weights(req.weights), 'the given weights'
            search = linear_search.resolve(req.env_id, 1, req.episodes, req.max_steps, 1, self.defaults)
            lengths = linear_search.evaluate(search.dynamics, weights, search.episodes, search.max_steps, req.seed)
            return EvaluatePolicyResponse(success=True, message=f'{counted(search.episodes, "episode")} of '
                                          f'{search.dynamics.env_id} with {whose}',
                                          lengths=[int(v) for v in lengths], avg_length=float(lengths.mean()))
        except RequestError as e:
            return EvaluatePolicyResponse(success=False, message=str(e))

    def _on_act(self, req):
        policy = self.policy
        if policy is None:
            return ActResponse(success=False, message='no policy yet: run a search or load a policy file', action=-1)
        try:
            return ActResponse(success=True, message=f'the node\'s policy, from {policy.origin}',
                               action=linear_search.act(policy.weights, req.state))
        except RequestError as e:
            return ActResponse(success=False, message=str(e), action=-1)

    def _on_load_policy(self, req):
        return answer_load(req.path, LinearPolicy.kind, self._install)


def main():
    run_node('cartpole_search', CartPoleSearchNode)
