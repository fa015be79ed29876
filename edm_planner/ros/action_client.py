"""An rclpy ActionClient whose answers cannot overtake their requests (rclpy 7.1, ROS 2 Jazzy).

``ActionClient.send_goal_async`` sends the goal request and only then files
the future that the answer completes. With the executor spinning in another
thread (a cell controller, the demo, the tests), an answer that arrives in
between is dropped ("Ignoring unexpected goal response. There may be more
than one action server ...") and the caller waits for ever: the demo met
exactly that. The same holds for cancel and result requests (ros2/rclpy
issue 1123; later rclpy releases add a lock). Here a lock is held from the
send until the future is filed, and the executor's ``execute`` passes that
lock before it looks the answer up. Hand-written because the fix is not in
the Jazzy wheels.
"""

import threading

from rclpy.action import ActionClient


class LockedActionClient(ActionClient):
    """``rclpy.action.ActionClient`` with the request/answer race closed; same interface."""

    def __init__(self, *args, **kwargs):
        self._filing = threading.RLock()
        super().__init__(*args, **kwargs)

    def send_goal_async(self, *args, **kwargs):
        with self._filing:
            return super().send_goal_async(*args, **kwargs)

    def _cancel_goal_async(self, *args, **kwargs):
        with self._filing:
            return super()._cancel_goal_async(*args, **kwargs)

    def _get_result_async(self, *args, **kwargs):
        with self._filing:
            return super()._get_result_async(*args, **kwargs)

    async def execute(self, taken_data):
        with self._filing:          # a request being sent has filed its future once this passes
            pass
        return await super().execute(taken_data)
