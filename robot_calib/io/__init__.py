# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""robot_calib io."""
