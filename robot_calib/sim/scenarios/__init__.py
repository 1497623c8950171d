# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Simulation scenarios, one module each (discovered automatically).

Every ``<name>.py`` here defines ``SCENARIO = Scenario(name='<name>', ...)``;
see :mod:`robot_calib.sim.scenario` for how to write one.
"""
