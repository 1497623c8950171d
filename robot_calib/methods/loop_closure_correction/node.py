# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The ``loop_closure_correction`` node: ``imu``, ``odom``, ``scan`` -> ``loop_closure/odom``.

A thin wrapper of
:class:`robot_calib.methods.loop_closure_correction.pipeline.LoopClosurePipeline`
through :mod:`robot_calib.nodes.base`: it publishes the corrected pose
(nav_msgs/Odometry, the stamp of the odometry input) and one
``/diagnostics`` array per loop-closure attempt (keyframes tried, scores,
correction, time taken).
"""

import sys
from typing import Optional

from robot_calib.methods.loop_closure_correction.pipeline import LoopClosurePipeline
from robot_calib.nodes.base import run


def main(args: Optional[list] = None) -> None:
    """Run the node until shutdown."""
    sys.exit(run(LoopClosurePipeline, args))


if __name__ == '__main__':
    main()
