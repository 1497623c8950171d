# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The one API of every method variant, and the one batch runner over a recording.

Every method folder (:mod:`robot_calib.methods`) has a seed-faithful and an
improved variant; both are :class:`Estimator` s, so a pipeline, a benchmark
or a notebook drives either the same way:

- ``set_mounting(transform)``: a static transform ``base_frame -> sensor
  frame`` (REP-105: translation m, rotation quaternion w, x, y, z); the
  estimator keeps the ones whose child is a frame its samples come in;
- ``update(sample)``: one time-ordered core sample (:mod:`robot_calib.core.types`);
  returns what this sample produced (an estimate, a correction) or None;
- ``result()``: a frozen dataclass of everything estimated so far;
- ``reset()``: forget the state (parameters and mountings are kept).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Iterable, Optional, Protocol, runtime_checkable

from robot_calib.core.types import StaticTransform


@runtime_checkable
class Estimator(Protocol):
    """What every method variant offers (seed-faithful or improved)."""

    params: Any

    def set_mounting(self, transform: StaticTransform) -> None:
        """Take a static transform base_frame -> sensor frame (a mounting)."""

    def update(self, sample: Any) -> Any:
        """Process one time-ordered sample; return what it produced, or None."""

    def result(self) -> Any:
        """Return a frozen dataclass of the estimates so far."""

    def reset(self) -> None:
        """Forget the state; keep the parameters and the mountings."""


@dataclass(frozen=True)
class BatchRun:
    """What :func:`run_batch` returns: the final result and the per-sample outputs kept."""

    result: Any
    outputs: list


def run_batch(estimator: Estimator, samples: Iterable[Any],
              keep: Optional[Callable[[Any, Any], bool]] = None) -> BatchRun:
    """
    Feed a whole recording to ``estimator`` and return its result.

    ``samples`` are core samples in time order; static transforms among them go
    to :meth:`Estimator.set_mounting`, everything else to :meth:`Estimator.update`.
    The outputs of ``update`` that are not None are kept when ``keep(sample,
    output)`` says so (all of them when ``keep`` is None).
    """
    outputs = []
    for sample in samples:
        if isinstance(sample, StaticTransform):
            estimator.set_mounting(sample)
            continue
        out = estimator.update(sample)
        if out is not None and (keep is None or keep(sample, out)):
            outputs.append(out)
    return BatchRun(estimator.result(), outputs)
