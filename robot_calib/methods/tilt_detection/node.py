# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The ``tilt_detection`` node: ``imu`` in; ``tilt/imu``, ``tilt/fall_alert``, ``/diagnostics``.

A thin wrapper of :class:`robot_calib.methods.tilt_detection.pipeline.TiltPipeline`
through :mod:`robot_calib.nodes.base` (parameters from
:class:`robot_calib.methods.tilt_detection.params.TiltParams`).
"""

from __future__ import annotations

import sys
from typing import Optional


def main(args: Optional[list[str]] = None) -> None:
    """Run the node until shutdown."""
    from robot_calib.nodes.base import run
    from robot_calib.methods.tilt_detection.pipeline import TiltPipeline
    sys.exit(run(TiltPipeline, args))


if __name__ == '__main__':
    main()
