# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Simulator: a 2D world, differential-drive and steered-wheel robots, and their sensors.

Public API (fixed, used by the CLI and the other methods' tests/benchmarks):

- :func:`simulate` (scenario, out, seed=0, duration=None, overrides=None,
  storage='mcap') writes the ROS 2 bag folder ``out`` and ``<out>.truth.json``
  and returns the truth dict;
- :func:`run_scenario` (name, seed=0, duration=None, overrides=None) does the
  same in memory and returns a :class:`SimResult`;
- :data:`SCENARIOS`: name -> :class:`Scenario`, discovered from
  ``robot_calib/sim/scenarios/*.py`` (see :mod:`robot_calib.sim.scenario` for
  how to add one);
- :class:`SimError` (a ValueError with a one-line message).

Parameters: :class:`~robot_calib.sim.params.SimParams` (``config/sim.yaml``).
"""

from robot_calib.sim.engine import run_scenario, run_setup, SimError, SimResult, simulate
from robot_calib.sim.params import SimParams
from robot_calib.sim.scenario import BuildContext, Scenario, SCENARIOS, Setup

__all__ = ['BuildContext', 'run_scenario', 'run_setup', 'Scenario', 'SCENARIOS', 'Setup',
           'SimError', 'SimParams', 'SimResult', 'simulate']
