# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Declare a core params dataclass as ROS parameters and read it back, validated."""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.node import Node

from robot_calib.core.params import describe, from_flat, ParamInfo

_ROS_TYPES = {
    bool: ParameterType.PARAMETER_BOOL,
    int: ParameterType.PARAMETER_INTEGER,
    float: ParameterType.PARAMETER_DOUBLE,
    str: ParameterType.PARAMETER_STRING,
}


def _descriptor(info: ParamInfo) -> ParameterDescriptor:
    unit = f' [{info.unit}]' if info.unit else ''
    extra = f' One of {list(info.choices)}.' if info.choices else ''
    if info.value_type is list:
        is_num = not info.default or isinstance(info.default[0], (int, float))
        ptype = ParameterType.PARAMETER_DOUBLE_ARRAY if is_num \
            else ParameterType.PARAMETER_STRING_ARRAY
    else:
        ptype = _ROS_TYPES.get(info.value_type, ParameterType.PARAMETER_STRING)
    return ParameterDescriptor(name=info.name, type=ptype,
                               description=f'{info.doc}{unit}{extra}', dynamic_typing=True)


def declare_params(node: Node, params_type: type) -> Any:
    """
    Declare every field of ``params_type`` on ``node`` and return the validated instance.

    Raises :class:`robot_calib.core.params.ParamError` with a one-line message
    when a value has the wrong type or is out of range.
    """
    values = {}
    for info in describe(params_type):
        default = info.default
        if isinstance(default, list):
            default = [float(v) for v in default] if (not default or isinstance(
                default[0], (int, float))) else list(default)
        node.declare_parameter(info.name, default, _descriptor(info))
        values[info.name] = node.get_parameter(info.name).value
    return from_flat(params_type, values)
