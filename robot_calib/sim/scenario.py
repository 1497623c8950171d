# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Scenarios: what world, which robot settings and which motion a simulation runs.

How to add a scenario
=====================
Create ``robot_calib/sim/scenarios/<name>.py`` (the file name IS the
scenario name used by ``robot-calib simulate <name>``). It must define a
module-level ``SCENARIO = Scenario(...)`` whose ``name`` equals the file
name; it is discovered automatically (no registration anywhere else)::

    import math

    from robot_calib.sim.motion import Plan
    from robot_calib.sim.scenario import BuildContext, Scenario, Setup
    from robot_calib.sim.world import World


    def build(ctx: BuildContext) -> Setup:
        world = World().add_room(20.0, 2.0).add_box(10.0, 1.0, 0.4, 0.4)
        lap = Plan().straight(16.0, 0.5).stop(1.0).turn(math.pi, 0.8).stop(1.0)
        plan = Plan().stop(2.0).repeat(lap, until=ctx.duration)
        return Setup(world=world, plan=plan, start=(2.0, 1.0, 0.0))


    SCENARIO = Scenario(
        name='corridor',
        description='Drive up and down a 20 m corridor (differential drive).',
        build=build,
        duration=60.0,
        defaults={'imu.gyro_bias': [0.0, 0.0, 0.002], 'lidar.range_max': 8.0})

(plus the two copyright lines, a module docstring and function docstrings as
everywhere; ``scenarios/drive.py`` is a complete example).

The pieces:

- ``Scenario.defaults``: ``{dotted parameter name: value}`` that replace the
  :class:`~robot_calib.sim.params.SimParams` defaults for this scenario
  (robot type, rates, sensor errors). The user's ``--set`` overrides win
  over them. Use ``'robot.drive_type': 'steered_wheel'`` for the tricycle.
- ``build(ctx)`` receives a :class:`BuildContext`: ``ctx.params`` (the final
  parameters after defaults and overrides; read, do not change),
  ``ctx.duration`` (s), ``ctx.seed`` and ``ctx.rng`` (a generator reserved for
  the scenario, e.g. random obstacle layouts, independent of sensor noise).
- It returns a :class:`Setup`: ``world`` (a :class:`~robot_calib.sim.world.World`
  of wall/obstacle segments and terrain features: ``add_room``, ``add_box``,
  ``add_polygon``, ``add_circle``, ``add_segment``, ``add_terrain(Ramp|Bump|Step)``),
  ``start`` (x, y, yaw of base_link in the world, m and rad), ``plan`` (a
  :class:`~robot_calib.sim.motion.Plan`: ``stop``, ``twist``, ``straight``,
  ``turn``, ``arc``, ``wheels``, ``steer``, ``profile``, ``goto``, ``face``,
  ``follow_wall``, ``custom``, ``tip_over``, ``repeat``), and optionally
  ``truth`` (extra scenario facts for ``truth.json``, e.g. the reference
  wall angles; JSON-able values, merged into ``truth.json`` without replacing
  the engine's keys).
- The plan is padded with a stop or cut to the duration. ``repeat(lap,
  until=ctx.duration)`` appends enough laps (closed-loop steps count as
  instant there). A stateful ``custom`` controller in a repeated lap must be
  given as a factory (``custom(make, timeout, factory=True)``) so each lap
  starts fresh; ``goto``/``face``/``follow_wall`` already are.
- Closed-loop steps see the TRUE state (``motion.State``: t, x, y, yaw, v, w,
  world), as if a perfect localisation ran on the robot; open-loop steps are
  affected by the wheel errors like a real robot driving blind.
- Tilt: terrain features give roll, pitch and height under the wheels;
  ``plan.tip_over(axis='pitch'|'roll', direction=+1|-1, angle=..., mode=
  'scripted'|'free', duration=...)`` tips the robot over (see
  :class:`~robot_calib.sim.motion.TipOver`); the IMU and the lidar follow.
- Tests and tools can run a hand-made :class:`Setup` without registering it:
  ``robot_calib.sim.run_setup(setup, engine.make_params(None, overrides), duration)``.
- Time-dependent errors (``wheels.slip_episodes``, gyro drift, warm-up) are
  given in seconds from the start of the run.

The engine (:mod:`robot_calib.sim.engine`) then integrates the true state,
simulates every sensor and returns a :class:`~robot_calib.sim.engine.SimResult`.
Test a new scenario with ``run_scenario('<name>', duration=10)``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
import importlib
import pkgutil
from typing import Any, Callable, Iterator, Optional

import numpy as np

from robot_calib.sim.motion import Plan
from robot_calib.sim.params import SimParams
from robot_calib.sim.world import World


@dataclass
class BuildContext:
    """What a scenario's ``build`` gets: final params, duration (s), seed and its own rng."""

    params: SimParams
    duration: float
    seed: int
    rng: np.random.Generator


@dataclass
class Setup:
    """What a scenario's ``build`` returns (see the module docstring)."""

    world: World
    plan: Plan
    start: tuple = (0.0, 0.0, 0.0)
    truth: dict = field(default_factory=dict)


@dataclass
class Scenario:
    """A named scenario: one-line description, default duration (s), param defaults, builder."""

    name: str
    description: str
    build: Callable[[BuildContext], Setup]
    duration: float = 120.0
    defaults: dict = field(default_factory=dict)


@dataclass
class BrokenScenario:
    """A scenario module that failed to import (reported when it is used)."""

    name: str
    error: str
    description: str = 'failed to load'


class _Registry(Mapping):
    """Scenarios discovered lazily from ``robot_calib/sim/scenarios/*.py``."""

    def __init__(self) -> None:
        self._items: Optional[dict[str, Any]] = None

    def _load(self) -> dict[str, Any]:
        if self._items is None:
            from robot_calib.sim import scenarios as pkg
            items: dict[str, Any] = {}
            for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda i: i.name):
                if info.name.startswith('_'):
                    continue
                try:
                    module = importlib.import_module(f'{pkg.__name__}.{info.name}')
                    scenario = getattr(module, 'SCENARIO')
                    if not isinstance(scenario, Scenario) or scenario.name != info.name:
                        raise TypeError('SCENARIO must be a Scenario named like its file')
                    items[info.name] = scenario
                except Exception as exc:  # one broken scenario must not hide the others
                    items[info.name] = BrokenScenario(info.name, f'{type(exc).__name__}: {exc}')
            self._items = items
        return self._items

    def __getitem__(self, name: str) -> Any:
        return self._load()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._load())

    def __len__(self) -> int:
        return len(self._load())

    def reload(self) -> None:
        """Forget the discovered scenarios (they are found again on next use)."""
        self._items = None


SCENARIOS = _Registry()
"""name -> :class:`Scenario` for every module in ``robot_calib/sim/scenarios``."""
