# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Helpers for the in-process rclpy tests."""

from typing import Callable


def spin_until(executor, condition: Callable[[], object], steps: int = 100,
               timeout: float = 0.02) -> bool:
    """Spin ``executor`` until ``condition()`` is true, at most ``steps`` times ``timeout`` s."""
    for _ in range(steps):
        executor.spin_once(timeout_sec=timeout)
        if condition():
            return True
    return False


def without_input_health(append: Callable[[object], None]) -> Callable[[object], None]:
    """Wrap a /diagnostics callback so that it skips the nodes' input-health statuses."""
    def callback(msg) -> None:
        if not any(s.name.endswith(': inputs') for s in msg.status):
            append(msg)
    return callback


def executor_with(*nodes):
    """Return a single-threaded rclpy executor spinning ``nodes``."""
    from rclpy.executors import SingleThreadedExecutor
    executor = SingleThreadedExecutor()
    for node in nodes:
        executor.add_node(node)
    return executor
