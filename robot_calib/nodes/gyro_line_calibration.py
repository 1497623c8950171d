# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The ``gyro_line_calibration`` node: ``imu`` + ``odom`` + ``scan`` -> ``gyro_line/odom``.

A thin wrapper of :class:`robot_calib.pipelines.gyro_line_calibration.GyroLinePipeline`
through :mod:`robot_calib.nodes.base`; it also publishes ``/diagnostics`` and,
in seed mode, listens to ``gyro_line/edge_following`` (std_msgs/Bool).
"""

import sys
from typing import Optional

from robot_calib.nodes.base import run
from robot_calib.pipelines.gyro_line_calibration import GyroLinePipeline


def main(args: Optional[list] = None) -> None:
    """Run the node until shutdown."""
    sys.exit(run(GyroLinePipeline, args))


if __name__ == '__main__':
    main()
