"""cartpole_search: the course's CartPole random search served over ROS.

ROS Parameters
    ~env_id (str, CartPole-v1), ~iterations (int, 100), ~episodes (int, 100), ~final_episodes (int, 100):
        what zero or empty request fields mean.
    ~output_dir (str, $ROS_HOME/robot_ai): where plots and videos are written; requests never name paths.

ROS Services
    ~random_search (robot_ai/RandomSearch): run a search; its best weights become the current policy.
    ~evaluate (robot_ai/EvaluatePolicy): play episodes with given weights (empty: the current policy).
    ~act (robot_ai/Act): the current policy's action for one state.

ROS Actions
    ~search (robot_ai/RandomSearchAction): the same search as a preemptable goal, feedback per candidate.

ROS Publishers
    ~progress (robot_ai/SearchProgress): after every candidate of any running search.

Bad requests get success: false and a message that says what is allowed; the node keeps serving.
"""
import os
import subprocess
import sys
import threading
import time

import actionlib
import rospkg
import rospy

from robot_ai import cartpole_search as cs
from robot_ai.plot_worker import job_of
from robot_ai.msg import RandomSearchAction, RandomSearchFeedback, RandomSearchResult, SearchProgress
from robot_ai.srv import (Act, ActResponse, EvaluatePolicy, EvaluatePolicyResponse, RandomSearch,
                          RandomSearchResponse)


class CartPoleSearchNode(object):

    def __init__(self):
        self.defaults = dict(env_id=rospy.get_param('~env_id', 'CartPole-v1'),
                             iterations=int(rospy.get_param('~iterations', 100)),
                             episodes=int(rospy.get_param('~episodes', 100)),
                             final_episodes=int(rospy.get_param('~final_episodes', 100)))
        self.output_dir = os.path.expanduser(rospy.get_param(
            '~output_dir', os.path.join(rospkg.get_ros_home(), 'robot_ai')))
        self.models = {}
        cs.resolve(defaults=self.defaults)  # a bad default is a clear error at start, not at the first call
        self.best_weights = None
        self.search_lock = threading.Lock()  # one search at a time; later requests wait their turn
        self.plotter = None
        self._start_plotter()
        self.progress_pub = rospy.Publisher('~progress', SearchProgress, queue_size=100)
        self.services = [rospy.Service('~random_search', RandomSearch, self._on_random_search),
                         rospy.Service('~evaluate', EvaluatePolicy, self._on_evaluate),
                         rospy.Service('~act', Act, self._on_act)]
        self.action = actionlib.SimpleActionServer('~search', RandomSearchAction, self._on_goal, auto_start=False)
        self.action.start()
        rospy.loginfo('cartpole_search ready: defaults %s, artifacts in %s', self.defaults, self.output_dir)

    # ------------------------------------------------------------------------------------- the search
    def _model(self, env_id):
        if env_id not in self.models:
            self.models[env_id] = cs.CartPoleModel(env_id)
        return self.models[env_id]

    def _search(self, req, feedback=None, should_stop=None):
        """Run the search of a RandomSearch request or goal; return the fields of the response."""
        model, iterations, episodes, max_steps, final_episodes = cs.resolve(
            req.env_id, req.iterations, req.episodes, req.max_steps, req.final_episodes, self.defaults)
        model = self._model(model.env_id)
        seed = int(req.seed) % (2 ** 64)  # default_rng takes non-negative seeds; keep negatives distinct

        def progress(i, avg, best, elapsed):
            self.progress_pub.publish(SearchProgress(iteration=i, iterations=iterations, last_avg_length=avg,
                                                     best_avg_length=best, elapsed=elapsed))
            if feedback is not None:
                feedback(i, iterations, best, elapsed)
            rospy.loginfo_throttle(2.0, 'search: candidate %d/%d, best average %.1f' % (i, iterations, best))

        with self.search_lock:
            t0 = time.time()
            result = cs.random_search(model, iterations, episodes, max_steps, seed, final_episodes,
                                      progress=progress, should_stop=should_stop)
            if result.cancelled:
                return None, result
            self.best_weights = result.best_weights.copy()
            stem = cs.artifact_stem(self.output_dir, result)
            plot_path = stem + '.png'
            self._plot(result, plot_path)  # drawn by another process: the answer does not wait for it
            video_path = ''
            if req.record_video:
                video_path, _ = cs.record_video(model.env_id, result.best_weights, max_steps, seed, stem + '.mp4')
            elapsed = time.time() - t0
        message = ('best average %.1f of %d candidates x %d episodes (%s, seed %d); final %.1f over %d episodes'
                   % (result.best_avg_length, iterations, episodes, model.env_id, req.seed,
                      result.final_avg_length, final_episodes))
        rospy.loginfo(message)
        return dict(success=True, message=message, best_weights=list(result.best_weights),
                    best_avg_length=result.best_avg_length, avg_lengths=list(result.avg_lengths),
                    final_avg_length=result.final_avg_length, plot_path=plot_path, video_path=video_path,
                    elapsed=elapsed), result

    def _start_plotter(self):
        self.plotter = subprocess.Popen([sys.executable, '-m', 'robot_ai.plot_worker'], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, text=True, bufsize=1)
        threading.Thread(target=self._log_plots, args=(self.plotter,), name='plots', daemon=True).start()

    def _log_plots(self, plotter):
        for line in plotter.stdout:
            rospy.loginfo('learning curve %s', line.strip())

    def _plot(self, result, path):
        """Hand a plot to the plot process (restarted if it died); a plot never takes the node down."""
        for _ in range(2):
            if self.plotter.poll() is not None:
                rospy.logwarn('the plot process ended (status %s); starting another', self.plotter.returncode)
                self._start_plotter()
            try:
                self.plotter.stdin.write(job_of(result, path))
                self.plotter.stdin.flush()
                return
            except (BrokenPipeError, OSError) as e:
                rospy.logwarn('could not hand the plot %s to the plot process: %s', path, e)
        rospy.logerr('learning curve not written: %s', path)

    # ------------------------------------------------------------------------------------- handlers
    def _on_random_search(self, req):
        try:
            fields, _ = self._search(req)
            return RandomSearchResponse(**fields)
        except cs.SearchError as e:
            return RandomSearchResponse(success=False, message=str(e))
        except Exception as e:
            rospy.logerr('random_search failed: %s', e)
            return RandomSearchResponse(success=False, message='search failed: %s' % e)

    def _on_goal(self, goal):
        def feedback(i, n, best, elapsed):
            self.action.publish_feedback(RandomSearchFeedback(iteration=i, iterations=n, best_avg_length=best,
                                                              elapsed=elapsed))
        try:
            fields, result = self._search(goal, feedback, should_stop=self.action.is_preempt_requested)
        except cs.SearchError as e:
            self.action.set_aborted(RandomSearchResult(success=False, message=str(e)), str(e))
            return
        except Exception as e:
            rospy.logerr('search goal failed: %s', e)
            self.action.set_aborted(RandomSearchResult(success=False, message='search failed: %s' % e))
            return
        if fields is None:
            msg = 'cancelled after %d of %d candidates' % (len(result.avg_lengths), result.iterations)
            self.action.set_preempted(RandomSearchResult(
                success=False, message=msg, avg_lengths=list(result.avg_lengths),
                best_avg_length=float(result.avg_lengths.max()) if len(result.avg_lengths) else 0.0), msg)
            return
        self.action.set_succeeded(RandomSearchResult(**fields), fields['message'])

    def _on_evaluate(self, req):
        try:
            if len(req.weights) == 0:
                if self.best_weights is None:
                    raise cs.SearchError('no current policy yet: run a search first or give 4 weights')
                weights = self.best_weights
            else:
                weights = cs.check_weights(req.weights)
            model, _, episodes, max_steps, _ = cs.resolve(req.env_id, 1, req.episodes, req.max_steps, 1,
                                                          self.defaults)
            lengths = cs.evaluate(self._model(model.env_id), weights, episodes, max_steps,
                                  int(req.seed) % (2 ** 64))
            return EvaluatePolicyResponse(success=True, message='%d episodes of %s' % (episodes, model.env_id),
                                          lengths=[int(v) for v in lengths], avg_length=float(lengths.mean()))
        except cs.SearchError as e:
            return EvaluatePolicyResponse(success=False, message=str(e))

    def _on_act(self, req):
        if self.best_weights is None:
            return ActResponse(success=False, message='no current policy yet: run a search first', action=-1)
        try:
            return ActResponse(success=True, message='', action=cs.act(self.best_weights, req.state))
        except cs.SearchError as e:
            return ActResponse(success=False, message=str(e), action=-1)


def main():
    rospy.init_node('cartpole_search')
    CartPoleSearchNode()
    rospy.spin()
