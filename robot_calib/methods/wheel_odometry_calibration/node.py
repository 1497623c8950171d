# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The ``wheel_odometry_calibration`` node (thin rclpy wrapper) and its ``--plan`` help."""

from __future__ import annotations

import sys
from typing import Optional

PLAN = """wheel_odometry_calibration: the calibration drive it needs

Record or drive live with: wheel data (joint_states with the wheel joints, or odom),
a 2D lidar on `scan`, and /tf_static base_link -> lidar frame (or set lidar_x/y/yaw).
Drive in a room with walls in view (not a long featureless corridor), slowly (< 0.5 m/s),
on a grippy floor:

  1. Straight segments: at least 5 straight runs of 2-4 m, forward (the wheel radius and
     the steering zero offset come from these; the seed method (mode:=seed) uses only
     straight stages and needs `seed.consecutive_stages` consistent ones in a row).
  2. Turns both ways: at least 3 left and 3 right turns of 90 deg or more
     (differential: turn on the spot and in arcs; steered wheel: full steering lock both
     ways, then medium angles) - track width, wheel base, steering scale and lidar pose.
  3. Repeat 1-2 two or three times (5-10 minutes in total is plenty).

Parameters: drive_type (auto | differential | steered_wheel), nominal wheel_radius, wheel_base,
track_width (left/right_wheel_radius), joint names steering_joint / traction_joint /
left_wheel_joint / right_wheel_joint, output_dir.
Progress and estimates: wheel_calibration/status (diagnostic_msgs/DiagnosticArray);
the verdict says `converged` or what the drive still lacks. At shutdown the result is
written to <output_dir>/wheel_calibration.yaml, ready to paste into the robot config.
"""


def main(args: Optional[list[str]] = None) -> None:
    """Run the node; ``--plan`` prints the calibration drive and exits 0."""
    argv = sys.argv[1:] if args is None else list(args)
    if '--plan' in argv:
        print(PLAN)
        sys.exit(0)
    from robot_calib.nodes.base import run
    from robot_calib.methods.wheel_odometry_calibration.pipeline import WheelCalibrationPipeline
    sys.exit(run(WheelCalibrationPipeline, args))


if __name__ == '__main__':
    main()
