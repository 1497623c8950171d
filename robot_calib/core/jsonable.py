# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Turn results (numpy scalars and arrays, tuples, paths) into JSON-ready Python values."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def jsonable(value: Any) -> Any:
    """
    Return ``value`` as plain JSON types.

    Dicts get string keys, tuples and arrays become lists, non-finite floats
    become None (JSON has no NaN), paths and unknown objects become strings.
    """
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return v if math.isfinite(v) else None
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if value is None or isinstance(value, str):
        return value
    return str(value)
