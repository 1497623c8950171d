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
          minimum: Optional[float] = None, maximum: Optional[float] = None,
          length: Optional[int] = None, length_multiple: Optional[int] = None,
          items: Optional[type] = None) -> Any:
    """
    Declare a parameter field with its default, unit ('' if none), description and limits.

    A list parameter also declares its shape: ``length`` (exact number of
    elements) or ``length_multiple`` (the length is a multiple of it, e.g. groups
    of four numbers), and the element type ``items`` (taken from the default's
    elements when omitted). ``minimum`` and ``maximum`` then apply to every
    element; float elements, like float parameters, must be finite.
    """
    if isinstance(default, list):
        if (length is None) == (length_multiple is None):
            raise TypeError('a list parameter needs exactly one of length= or length_multiple=')
        items = items if items is not None else _item_type(default)
        if items is None:
            raise TypeError('a list parameter with an empty or mixed default needs items=')
    meta = {'unit': unit, 'doc': doc,
            'choices': tuple(choices) if choices is not None else None,
            'minimum': minimum, 'maximum': maximum,
            'length': length, 'length_multiple': length_multiple, 'items': items}
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _item_type(values: list) -> Optional[type]:
    """Return the element type of a non-empty default list (numbers are float), else None."""
    if values and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        return float
    if values and all(isinstance(v, str) for v in values):
        return str
    return None


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
    length: Optional[int] = None
    length_multiple: Optional[int] = None
    items: Optional[type] = None


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
                             meta.get('maximum'), meta.get('length'),
                             meta.get('length_multiple'), meta.get('items')))
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


def _scalar(tp: type, value: Any) -> Any:
    """Convert one value to ``tp`` (bool, int, float, str); raise ValueError or TypeError."""
    if tp is bool:
        if isinstance(value, str):
            low = value.strip().lower()
            if low not in ('true', 'false', '1', '0', 'yes', 'no'):
                raise ValueError(value)
            return low in ('true', '1', 'yes')
        return bool(value)
    if tp is int:
        if isinstance(value, float) and not value.is_integer():
            raise ValueError(value)
        return int(value)
    if tp is float:
        if isinstance(value, str) and value.strip().lower() in ('pi', '-pi'):
            return math.copysign(math.pi, -1.0 if value.strip()[0] == '-' else 1.0)
        return float(value)
    if tp is str:
        return str(value)
    return value


def _as_list(info: ParamInfo, value: Any) -> list:
    """Return ``value`` as a list of the parameter's element type ('a,b' and '[a, b]' parse)."""
    if isinstance(value, str):
        value = [v.strip() for v in value.strip().strip('[]').split(',') if v.strip()]
    if isinstance(value, (dict, set)):
        raise TypeError(value)
    value = list(value)
    return value if info.items is None else [_scalar(info.items, v) for v in value]


_ITEM_NAMES = {float: 'numbers', int: 'integers', str: 'strings', bool: 'booleans'}


def _expected(info: ParamInfo) -> str:
    """Return what a parameter expects, for the one-line error message."""
    if info.value_type is not list:
        return info.value_type.__name__
    kind = _ITEM_NAMES.get(info.items, 'values')
    if info.length is not None:
        return f'a list of {info.length} {kind}'
    if info.length_multiple is not None:
        return f'a list of {kind} in groups of {info.length_multiple}'
    return f'a list of {kind}'


def coerce(info: ParamInfo, value: Any) -> Any:
    """
    Convert ``value`` to the parameter's type and check it; raise ParamError (one line).

    Checked: the type (of every element of a list), a list's length, choices,
    finiteness of floats (NaN and inf are never a parameter value) and the
    limits (of every element of a list).
    """
    tp = info.value_type
    try:
        value = _as_list(info, value) if tp is list else _scalar(tp, value)
    except (TypeError, ValueError):
        raise ParamError(f'parameter {info.name}: expected {_expected(info)}, '
                         f'got {value!r}') from None
    if tp is list and (info.length is not None and len(value) != info.length or (
            info.length_multiple and len(value) % info.length_multiple)):
        raise ParamError(f'parameter {info.name}: expected {_expected(info)}, '
                         f'got {len(value)} element(s) {value!r}')
    if info.choices is not None and value not in info.choices:
        raise ParamError(f'parameter {info.name}: {value!r} is not one of {list(info.choices)}')
    for v in value if tp is list else (value,):
        if isinstance(v, float) and not math.isfinite(v):
            raise ParamError(f'parameter {info.name}: must be finite, got {value!r}')
        if info.minimum is not None and v < info.minimum:
            raise ParamError(f'parameter {info.name}: {value!r} is below the minimum '
                             f'{info.minimum}')
        if info.maximum is not None and v > info.maximum:
            raise ParamError(f'parameter {info.name}: {value!r} is above the maximum '
                             f'{info.maximum}')
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
