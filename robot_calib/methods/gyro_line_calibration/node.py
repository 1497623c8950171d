# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The ``gyro_line_calibration`` node: ``imu`` + ``odom`` + ``scan`` -> ``gyro_line/odom``.

A thin wrapper of :class:`robot_calib.methods.gyro_line_calibration.pipeline.GyroLinePipeline`
through :mod:`robot_calib.nodes.base`; it also publishes ``/diagnostics`` and,
in seed mode, listens to ``gyro_line/edge_following`` (std_msgs/Bool).
"""

import sys
from typing import Optional

from robot_calib.methods.gyro_line_calibration.pipeline import GyroLinePipeline
from robot_calib.nodes.base import run


def main(args: Optional[list] = None) -> None:
    """Run the node until shutdown."""
    sys.exit(run(GyroLinePipeline, args))


if __name__ == '__main__':
    main()
