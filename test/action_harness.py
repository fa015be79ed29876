"""An action client for the tests: goals over DDS with a deadline on every wait, feedback recorded with its time.

Used with ``ros_harness.InProcessRos`` (a client node on a private context, an executor spinning in a
thread): the futures of the action client (rclpy's, with its request/answer race closed) are completed by that executor, and every wait
here polls them against a deadline, so a server that never answers fails the test with what it waited for.
"""

import time

from action_msgs.msg import GoalStatus

from edm_planner.ros.action_client import LockedActionClient

from ros_harness import wait_for

STATUS_NAMES = {GoalStatus.STATUS_SUCCEEDED: "SUCCEEDED", GoalStatus.STATUS_ABORTED: "ABORTED",
                GoalStatus.STATUS_CANCELED: "CANCELED", GoalStatus.STATUS_UNKNOWN: "UNKNOWN"}


class Goal:
    """One goal sent: its handle, the feedback received as (monotonic time, message), and its result."""

    def __init__(self, client, goal_msg, timeout):
        self.feedback = []
        self.sent_at = time.monotonic()
        future = client.send_goal_async(goal_msg, feedback_callback=self._on_feedback)
        self.handle = wait_for(future, timeout, f"goal request to {client._action_name}")
        self.accepted = bool(self.handle.accepted)
        self._result_future = self.handle.get_result_async() if self.accepted else None
        self.name = client._action_name

    def _on_feedback(self, msg):
        self.feedback.append((time.monotonic(), msg.feedback))

    def wait_feedback(self, predicate, timeout, what="feedback"):
        """The first feedback message satisfying ``predicate`` (waiting up to ``timeout`` s for it)."""
        deadline = time.monotonic() + timeout
        seen = 0
        while True:
            for _, fb in self.feedback[seen:]:
                if predicate(fb):
                    return fb
            seen = len(self.feedback)
            if self.done():
                raise AssertionError(f"{self.name}: the goal ended before {what} (status {self.status_name()})")
            if time.monotonic() > deadline:
                raise TimeoutError(f"{self.name}: no {what} within {timeout:.0f} s ({seen} feedback messages)")
            time.sleep(0.02)

    def done(self):
        return self._result_future is not None and self._result_future.done()

    def cancel(self, timeout=30.0):
        """Request cancel; returns the CancelGoal response."""
        return wait_for(self.handle.cancel_goal_async(), timeout, f"cancel of a {self.name} goal")

    def result(self, timeout):
        """(status, result message) once the goal has ended."""
        assert self.accepted, f"{self.name}: the goal was rejected"
        response = wait_for(self._result_future, timeout, f"result of a {self.name} goal")
        self.status, self.result_msg = response.status, response.result
        return response.status, response.result

    def status_name(self):
        done = self.done() and self._result_future.result()
        return STATUS_NAMES.get(done.status, str(done.status)) if done else "running"


class Actions:
    """Action clients of one node, created once per action name."""

    def __init__(self, node):
        self.node = node
        self.clients = {}

    def client(self, action_type, name, timeout=60.0):
        if name not in self.clients:
            client = LockedActionClient(self.node, action_type, name)
            if not client.wait_for_server(timeout_sec=timeout):
                raise TimeoutError(f"action server {name} not available after {timeout:.0f} s")
            self.clients[name] = client
        return self.clients[name]

    def send(self, action_type, name, goal_msg, timeout=60.0):
        """Send a goal; a :class:`Goal` (``accepted`` False when the server rejected it)."""
        return Goal(self.client(action_type, name, timeout), goal_msg, timeout)

    def run(self, action_type, name, goal_msg, timeout):
        """Send a goal and wait for its end: (Goal, status, result)."""
        goal = self.send(action_type, name, goal_msg)
        assert goal.accepted, f"{name}: goal rejected"
        status, result = goal.result(timeout)
        return goal, status, result

    def close(self):
        for client in self.clients.values():
            client.destroy()
        self.clients = {}
