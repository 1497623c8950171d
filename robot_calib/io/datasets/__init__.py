# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Loaders for the public data sets used in tests and benchmarks (one module each)."""
