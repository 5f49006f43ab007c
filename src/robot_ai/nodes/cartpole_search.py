"""cartpole_search: the course's CartPole random search served over ROS.

ROS Parameters
    ~env_id (str), ~iterations (int), ~episodes (int), ~final_episodes (int): what zero or empty request
        fields mean; unset, zero or empty: linear_search.DEFAULTS (CartPole-v1, 100, 100, 100).
    ~output_dir (str, "" = $ROS_HOME/robot_ai): where plots and videos are written; requests never name paths.

ROS Services
    ~random_search (robot_ai/RandomSearch): run a search; its best weights become the node's policy if their
        final average is at least the current policy's (so a small test search does not replace a good policy).
    ~evaluate (robot_ai/EvaluatePolicy): play episodes with given weights (empty: the node's policy).
    ~act (robot_ai/Act): the node's policy's action for one state.
    Every response that uses the node's policy says which search it came from.

ROS Actions
    ~search (robot_ai/RandomSearchAction): the same search as a preemptable goal, feedback per candidate.

ROS Publishers
    ~progress (robot_ai/SearchProgress): after every candidate of any running search.

Bad requests get success: false and a message that says what is allowed; the node keeps serving.
A response arrives before its plot: plot_path names the file being drawn (see agent_common).
"""
import threading
import time

import actionlib
import rospy

from robot_ai.cartpole import artifacts, linear_search
from robot_ai.cartpole.dynamics import RequestError
from robot_ai.nodes.agent_common import PlotProcess, agent_settings, answer, answer_goal, write_files
from robot_ai.msg import RandomSearchAction, RandomSearchFeedback, RandomSearchResult, SearchProgress
from robot_ai.srv import (Act, ActResponse, EvaluatePolicy, EvaluatePolicyResponse, RandomSearch,
                          RandomSearchResponse)


class CartPoleSearchNode(object):

    def __init__(self):
        self.defaults, self.output_dir = agent_settings(linear_search, 'searches')
        self.policy = None         # the best policy of any search so far: weights, final average, origin
        self.searches = 0
        self.search_lock = threading.Lock()  # one search at a time; later requests wait their turn
        self.plots = PlotProcess()
        self.progress_pub = rospy.Publisher('~progress', SearchProgress, queue_size=100)
        self.services = [rospy.Service('~random_search', RandomSearch, self._on_random_search),
                         rospy.Service('~evaluate', EvaluatePolicy, self._on_evaluate),
                         rospy.Service('~act', Act, self._on_act)]
        self.action = actionlib.SimpleActionServer('~search', RandomSearchAction, self._on_goal, auto_start=False)
        self.action.start()
        rospy.loginfo('cartpole_search ready: defaults %s, artifacts in %s', self.defaults, self.output_dir)

    # ------------------------------------------------------------------------------------- the search
    def _search(self, req, feedback=None, should_stop=None):
        """Run the search of a RandomSearch request or goal; return the fields of the response."""
        search = linear_search.resolve(req.env_id, req.iterations, req.episodes, req.max_steps,
                                       req.final_episodes, self.defaults)
        env_id, iterations = search.dynamics.env_id, search.iterations

        def progress(i, avg, best, elapsed):
            self.progress_pub.publish(SearchProgress(iteration=i, iterations=iterations, last_avg_length=avg,
                                                     best_avg_length=best, elapsed=elapsed))
            if feedback is not None:
                feedback(i, iterations, best, elapsed)
            rospy.loginfo_throttle(2.0, 'search: candidate %d/%d, best average %.1f' % (i, iterations, best))

        with self.search_lock:
            t0 = time.time()
            result = linear_search.random_search(search.dynamics, iterations, search.episodes, search.max_steps,
                                                 req.seed, search.final_episodes, progress=progress,
                                                 should_stop=lambda: rospy.is_shutdown() or bool(
                                                     should_stop and should_stop()))
            if result.cancelled:
                return None, result
            self.searches += 1
            kept = self._keep_better(result)
            weights = result.best_weights
            video = None if not req.record_video else (lambda path: artifacts.record_video(
                env_id, lambda obs: linear_search.act(weights, obs), search.max_steps, req.seed, path)[0])
            plot_path, video_path, files = write_files(self.plots, self.output_dir, 'search', env_id, req.seed,
                                                       artifacts.search_plot_job(result), video)
            elapsed = time.time() - t0
        message = ('best average %.1f of %d candidates x %d episodes (%s, seed %d); final %.1f over %d episodes; %s; %s'
                   % (result.best_avg_length, iterations, search.episodes, env_id, req.seed,
                      result.final_avg_length, search.final_episodes, kept, files))
        rospy.loginfo(message)
        return dict(success=True, message=message, best_weights=list(result.best_weights),
                    best_avg_length=result.best_avg_length, avg_lengths=list(result.avg_lengths),
                    final_avg_length=result.final_avg_length, plot_path=plot_path, video_path=video_path,
                    elapsed=elapsed), result

    def _keep_better(self, result):
        """Make the search's best the node's policy if its final average is at least the current policy's."""
        origin = 'search %d (%s, seed %d, %d x %d, final %.1f)' % (
            self.searches, result.env_id, result.seed, result.iterations, result.episodes, result.final_avg_length)
        if self.policy is not None and result.final_avg_length < self.policy['final']:
            return 'the node keeps its policy from %s' % self.policy['origin']
        self.policy = dict(weights=result.best_weights.copy(), final=result.final_avg_length, origin=origin)
        return 'its best is now the node\'s policy'

    # ------------------------------------------------------------------------------------- handlers
    def _on_random_search(self, req):
        return answer(lambda: self._search(req), RandomSearchResponse, 'search')

    def _on_goal(self, goal):
        def feedback(i, n, best, elapsed):
            self.action.publish_feedback(RandomSearchFeedback(iteration=i, iterations=n, best_avg_length=best,
                                                              elapsed=elapsed))

        def cancelled(result):
            avgs = result.avg_lengths
            return ('cancelled after %d of %d candidates' % (len(avgs), result.iterations),
                    dict(avg_lengths=list(avgs), best_avg_length=float(avgs.max()) if len(avgs) else 0.0))
        answer_goal(self.action, lambda: self._search(goal, feedback, self.action.is_preempt_requested),
                    RandomSearchResult, 'search', cancelled)

    def _on_evaluate(self, req):
        try:
            if len(req.weights) == 0:
                if self.policy is None:
                    raise RequestError('no policy yet: run a search first or give 4 weights')
                weights, whose = self.policy['weights'], 'the node\'s policy, from %s' % self.policy['origin']
            else:
                weights, whose = linear_search.check_weights(req.weights), 'the given weights'
            search = linear_search.resolve(req.env_id, 1, req.episodes, req.max_steps, 1, self.defaults)
            lengths = linear_search.evaluate(search.dynamics, weights, search.episodes, search.max_steps, req.seed)
            return EvaluatePolicyResponse(success=True, message='%d episodes of %s with %s' % (
                                              search.episodes, search.dynamics.env_id, whose),
                                          lengths=[int(v) for v in lengths], avg_length=float(lengths.mean()))
        except RequestError as e:
            return EvaluatePolicyResponse(success=False, message=str(e))

    def _on_act(self, req):
        if self.policy is None:
            return ActResponse(success=False, message='no policy yet: run a search first', action=-1)
        try:
            return ActResponse(success=True, message='the node\'s policy, from %s' % self.policy['origin'],
                               action=linear_search.act(self.policy['weights'], req.state))
        except RequestError as e:
            return ActResponse(success=False, message=str(e), action=-1)


def main():
    rospy.init_node('cartpole_search')
    try:
        CartPoleSearchNode()
    except (RequestError, ValueError) as e:
        rospy.logfatal('cartpole_search: bad parameter: %s', e)
        raise SystemExit(1)
    rospy.spin()
