# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The two ``loop_closure_correction`` variants by ``LoopClosureParams.mode``, and a factory."""

from __future__ import annotations

from typing import Optional

from robot_calib.methods.loop_closure_correction.improved import ImprovedLoopClosure
from robot_calib.methods.loop_closure_correction.params import LoopClosureParams
from robot_calib.methods.loop_closure_correction.seed import SeedLoopClosure
from robot_calib.methods.loop_closure_correction.variant_base import LoopClosureBase

VARIANTS: dict[str, type[LoopClosureBase]] = {
    SeedLoopClosure.mode: SeedLoopClosure,
    ImprovedLoopClosure.mode: ImprovedLoopClosure,
}
"""Estimator class by ``LoopClosureParams.mode``."""


def make_estimator(params: Optional[LoopClosureParams] = None) -> LoopClosureBase:
    """Return the variant ``params.mode`` selects (``improved`` by default)."""
    params = params if params is not None else LoopClosureParams()
    return VARIANTS[params.mode](params)
