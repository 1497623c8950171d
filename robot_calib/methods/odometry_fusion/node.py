# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The ``odometry_fusion`` node: ``imu`` + ``odom`` (or ``joint_states``) -> ``odometry/fused``.

A thin wrapper of :class:`robot_calib.methods.odometry_fusion.pipeline.FusionPipeline`
through :mod:`robot_calib.nodes.base`; it also publishes ``/diagnostics``.
"""

import sys
from typing import Optional

from robot_calib.methods.odometry_fusion.pipeline import FusionPipeline
from robot_calib.nodes.base import run


def main(args: Optional[list] = None) -> None:
    """Run the node until shutdown."""
    sys.exit(run(FusionPipeline, args))


if __name__ == '__main__':
    main()
