# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Parameter dataclasses: the single source of defaults, units and documentation.

Every method declares its parameters as a dataclass whose fields are made with
:func:`param`. Nested dataclasses give dotted names (``filter.gyro_noise``).
Nodes declare these as ROS parameters, replay reads them from the YAML file
and ``--set``, and ``config/robot_calib.yaml`` is generated from them.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from typing import Any, Iterable, Optional


class ParamError(ValueError):
    """A parameter value that is unknown, of the wrong type or out of range."""


def param(default: Any, unit: str, doc: str, *, choices: Optional[Iterable[Any]] = None,
          minimum: Optional[float] = None, maximum: Optional[float] = None) -> Any:
    """Declare a parameter field with its default, unit ('' if none), description and limits."""
    meta = {'unit': unit, 'doc': doc,
            'choices': tuple(choices) if choices is not None else None,
            'minimum': minimum, 'maximum': maximum}
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


@dataclasses.dataclass(frozen=True)
class ParamInfo:
    """Description of one flattened parameter."""

    name: str
    default: Any
    value_type: type
    unit: str
    doc: str
    choices: Optional[tuple]
    minimum: Optional[float]
    maximum: Optional[float]


def _resolved_types(cls: type) -> dict:
    return typing.get_type_hints(cls)


def _base_type(tp: Any) -> type:
    origin = typing.get_origin(tp)
    if origin is typing.Union:
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return _base_type(args[0])
    if origin in (list, tuple):
        return list
    if isinstance(tp, type):
        return tp
    return str


def describe(cls: type, prefix: str = '') -> list[ParamInfo]:
    """Return the flattened parameters of a params dataclass, in declaration order."""
    out = []
    hints = _resolved_types(cls)
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        name = prefix + f.name
        if dataclasses.is_dataclass(tp):
            out.extend(describe(tp, name + '.'))
            continue
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            raise TypeError(f'parameter {name} has no default')
        meta = f.metadata
        out.append(ParamInfo(name, default, _base_type(tp), meta.get('unit', ''),
                             meta.get('doc', ''), meta.get('choices'), meta.get('minimum'),
                             meta.get('maximum')))
    return out


def to_flat(params: Any, prefix: str = '') -> dict[str, Any]:
    """Return ``{dotted_name: value}`` of a params instance."""
    out = {}
    for f in dataclasses.fields(params):
        value = getattr(params, f.name)
        if dataclasses.is_dataclass(value):
            out.update(to_flat(value, prefix + f.name + '.'))
        else:
            out[prefix + f.name] = value
    return out


def coerce(info: ParamInfo, value: Any) -> Any:
    """Convert ``value`` to the parameter's type and check its limits; raise ParamError."""
    tp = info.value_type
    try:
        if tp is bool:
            if isinstance(value, str):
                low = value.strip().lower()
                if low not in ('true', 'false', '1', '0', 'yes', 'no'):
                    raise ValueError(value)
                value = low in ('true', '1', 'yes')
            else:
                value = bool(value)
        elif tp is int:
            if isinstance(value, float) and not value.is_integer():
                raise ValueError(value)
            value = int(value)
        elif tp is float:
            if isinstance(value, str) and value.strip().lower() in ('pi', '-pi'):
                value = math.copysign(math.pi, -1.0 if value.strip()[0] == '-' else 1.0)
            value = float(value)
        elif tp is list:
            if isinstance(value, str):
                value = [v.strip() for v in value.strip('[]').split(',') if v.strip()]
            value = list(value)
            if isinstance(info.default, list) and info.default and \
                    isinstance(info.default[0], (int, float)):
                value = [float(v) for v in value]
        elif tp is str:
            value = str(value)
    except (TypeError, ValueError):
        raise ParamError(f'parameter {info.name}: expected {tp.__name__}, got {value!r}') from None
    if info.choices is not None and value not in info.choices:
        raise ParamError(f'parameter {info.name}: {value!r} is not one of {list(info.choices)}')
    if isinstance(value, float) and not math.isfinite(value) and tp is float \
            and (info.minimum is not None or info.maximum is not None):
        raise ParamError(f'parameter {info.name}: must be finite, got {value!r}')
    if info.minimum is not None and value < info.minimum:
        raise ParamError(f'parameter {info.name}: {value!r} is below the minimum {info.minimum}')
    if info.maximum is not None and value > info.maximum:
        raise ParamError(f'parameter {info.name}: {value!r} is above the maximum {info.maximum}')
    return value


def from_flat(cls: type, values: dict[str, Any], strict: bool = True) -> Any:
    """Build a params instance from ``{dotted_name: value}``; unknown names raise ParamError."""
    infos = {i.name: i for i in describe(cls)}
    unknown = sorted(set(values) - set(infos))
    if unknown and strict:
        raise ParamError(f'unknown parameter(s) {unknown}; known: {sorted(infos)}')
    flat = {name: coerce(infos[name], v) for name, v in values.items() if name in infos}
    return _build(cls, flat, '')


def _build(cls: type, flat: dict[str, Any], prefix: str) -> Any:
    hints = _resolved_types(cls)
    kwargs = {}
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        name = prefix + f.name
        if dataclasses.is_dataclass(tp):
            kwargs[f.name] = _build(tp, flat, name + '.')
        elif name in flat:
            kwargs[f.name] = flat[name]
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ParamError(f'{cls.__name__}: {exc}') from None


def flatten_nested(tree: dict[str, Any], prefix: str = '') -> dict[str, Any]:
    """Flatten a nested mapping (as YAML gives it) into dotted names."""
    out = {}
    for key, value in tree.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            out.update(flatten_nested(value, name + '.'))
        else:
            out[name] = value
    return out
