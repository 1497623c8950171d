# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Registry of the method pipelines, by executable name (imported lazily)."""

from __future__ import annotations

import importlib
import importlib.util

REGISTRY = {
    'gyro_line_calibration': 'robot_calib.pipelines.gyro_line_calibration:GyroLinePipeline',
    'loop_closure_correction': 'robot_calib.pipelines.loop_closure_correction:LoopClosurePipeline',
    'tilt_detection': 'robot_calib.pipelines.tilt_detection:TiltPipeline',
    'odometry_fusion': 'robot_calib.pipelines.odometry_fusion:FusionPipeline',
    'wheel_odometry_calibration':
        'robot_calib.pipelines.wheel_odometry_calibration:WheelCalibrationPipeline',
}


def available() -> list[str]:
    """Return the names of the pipelines whose modules are present, in registry order."""
    names = []
    for name, target in REGISTRY.items():
        module = target.split(':')[0]
        if importlib.util.find_spec(module) is not None:
            names.append(name)
    return names


def load(name: str) -> type:
    """Return the pipeline class of executable ``name``; KeyError when unknown."""
    if name not in REGISTRY:
        raise KeyError(f'unknown node {name!r}; known: {", ".join(REGISTRY)}')
    module, cls = REGISTRY[name].split(':')
    return getattr(importlib.import_module(module), cls)
