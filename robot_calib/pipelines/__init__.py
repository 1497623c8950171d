# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The pipeline framework: the base class (:mod:`.base`), sample checks and stack export.

The registry of the method pipelines is :mod:`robot_calib.methods` (``REGISTRY``,
``available``, ``load``); this package never imports the methods.
"""
