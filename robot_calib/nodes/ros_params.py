# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Declare a core params dataclass as ROS parameters and read it back, validated.

Every descriptor carries the field's description, unit, allowed values and
range. A parameter the pipeline cannot apply while running is read-only (rcl
refuses ``ros2 param set`` with a reason); the others are checked and applied
live by :class:`robot_calib.nodes.base.PipelineNode`.
"""

from __future__ import annotations

import sys
from typing import Any, Iterable

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType)
from rclpy.exceptions import InvalidParameterValueException
from rclpy.node import Node

from robot_calib.core.params import describe, from_flat, ParamError, ParamInfo

_ROS_TYPES = {
    bool: ParameterType.PARAMETER_BOOL,
    int: ParameterType.PARAMETER_INTEGER,
    float: ParameterType.PARAMETER_DOUBLE,
    str: ParameterType.PARAMETER_STRING,
}


def _descriptor(info: ParamInfo, read_only: bool) -> ParameterDescriptor:
    unit = f' [{info.unit}]' if info.unit else ''
    extra = f' One of {list(info.choices)}.' if info.choices else ''
    if info.value_type is list:
        is_num = not info.default or isinstance(info.default[0], (int, float))
        ptype = ParameterType.PARAMETER_DOUBLE_ARRAY if is_num \
            else ParameterType.PARAMETER_STRING_ARRAY
    else:
        ptype = _ROS_TYPES.get(info.value_type, ParameterType.PARAMETER_STRING)
    live = '' if read_only else ' Applied live.'
    descriptor = ParameterDescriptor(name=info.name, type=ptype, read_only=read_only,
                                     description=f'{info.doc}{unit}{extra}{live}',
                                     dynamic_typing=True)
    if info.minimum is not None or info.maximum is not None:
        low = -sys.float_info.max if info.minimum is None else info.minimum
        high = sys.float_info.max if info.maximum is None else info.maximum
        if info.value_type is int:
            descriptor.integer_range = [IntegerRange(from_value=int(max(low, -2**63)),
                                                     to_value=int(min(high, 2**63 - 1)))]
        elif info.value_type is float:
            descriptor.floating_point_range = [FloatingPointRange(from_value=float(low),
                                                                  to_value=float(high))]
    return descriptor


def declare_params(node: Node, params_type: type, live: Iterable[str] = ()) -> Any:
    """
    Declare every field of ``params_type`` on ``node`` and return the validated instance.

    Fields not named in ``live`` are read-only. Raises
    :class:`robot_calib.core.params.ParamError` with a one-line message when a
    value has the wrong type or is out of range.
    """
    live = set(live)
    values = {}
    for info in describe(params_type):
        default = info.default
        if isinstance(default, list):
            default = [float(v) for v in default] if (not default or isinstance(
                default[0], (int, float))) else list(default)
        try:
            node.declare_parameter(info.name, default, _descriptor(info, info.name not in live))
        except InvalidParameterValueException as exc:
            given = getattr(node, '_parameter_overrides', {}).get(info.name)
            if given is not None:  # our own one-line reason, as replay gives it
                from_flat(params_type, {info.name: given.value})
            raise ParamError(f'{info.name}: {" ".join(str(exc).split())}') from None
        values[info.name] = node.get_parameter(info.name).value
    return from_flat(params_type, values)
