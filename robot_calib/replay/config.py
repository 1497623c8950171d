# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
What a replay is asked to do: nodes, remaps, parameter overrides and files, the output folder.

The parsers are shared with the command line (``robot-calib replay`` and
``--live``); every error is a :class:`ReplayError` with a one-line message.
"""

from __future__ import annotations

from collections import defaultdict
import dataclasses
import difflib
import importlib
import os
from pathlib import Path
import shutil
import tempfile
from typing import Any, Iterable, Mapping, Union

from robot_calib import methods
from robot_calib.core.params import describe, flatten_nested, from_flat, ParamError
from robot_calib.io.bags import normalize_topic
from robot_calib.pipelines.base import Pipeline

OUTPUT_BAG = 'output.mcap'
SUMMARY = 'summary.json'
REPORT = 'report.md'


class ReplayError(ValueError):
    """Bad replay input (nodes, topics, remaps, parameters, output folder): one-line message."""


NodeSpec = Union[str, type]


def parse_remaps(remaps: Union[None, Mapping[str, str], Iterable[str]]) -> list[tuple[str, str]]:
    """Parse ``FROM:=TO`` rules (or a mapping) into normalized ``(from, to)`` topic pairs."""
    if not remaps:
        return []
    items = remaps.items() if isinstance(remaps, Mapping) else None
    out = []
    if items is None:
        pairs = []
        for rule in remaps:
            if not isinstance(rule, str) or ':=' not in rule:
                raise ReplayError(f'bad --remap {rule!r}: expected FROM:=TO, e.g. imu:=/imu/data')
            pairs.append(tuple(rule.split(':=', 1)))
        items = pairs
    for src, dst in items:
        src, dst = str(src).strip(), str(dst).strip()
        if not src.strip('/') or not dst.strip('/') or ' ' in src or ' ' in dst \
                or ':=' in dst:
            raise ReplayError(f'bad --remap {src}:={dst}: expected FROM:=TO with two topic '
                              'names, e.g. imu:=/imu/data')
        out.append((normalize_topic(src), normalize_topic(dst)))
    return out


def parse_overrides(overrides: Union[None, Mapping[str, Any], Iterable[str]]
                    ) -> dict[str, dict[str, Any]]:
    """Parse ``NODE.PARAM=VALUE`` items (or a ``{'NODE.PARAM': value}`` mapping) by node."""
    out: dict[str, dict[str, Any]] = defaultdict(dict)
    if not overrides:
        return {}
    if isinstance(overrides, Mapping):
        items = list(overrides.items())
    else:
        items = []
        for item in overrides:
            if not isinstance(item, str) or '=' not in item:
                raise ReplayError(f'bad --set {item!r}: expected NODE.PARAM=VALUE, '
                                  'e.g. tilt_detection.fall_angle=0.6')
            key, value = item.split('=', 1)
            items.append((key, value))
    for key, value in items:
        key = str(key).strip()
        node, _, name = key.partition('.')
        if not node or not name or any(not part for part in name.split('.')):
            raise ReplayError(f'bad --set {key}={value}: expected NODE.PARAM=VALUE, '
                              'e.g. tilt_detection.fall_angle=0.6')
        out[node][name] = value.strip() if isinstance(value, str) else value
    return dict(out)


def node_of_key(key: str) -> str:
    """
    Return the node a parameter-file key addresses, as rcl matches it for replay's nodes.

    ``/**`` (and ``/**/*``) address every node and stay ``'/**'``; ``name``,
    ``/name``, ``/robot1/name`` and ``/**/name`` address the node ``name``
    (replay runs each node once, so the namespace part matches it).
    """
    text = str(key).strip()
    if text.strip('/') in ('**', '*', '**/*'):
        return '/**'
    return text.strip('/').split('/')[-1]


def load_params_file(path: Union[str, os.PathLike, None]) -> dict[str, dict[str, Any]]:
    """
    Read a ROS 2 parameter YAML (node -> ros__parameters -> nested or dotted keys).

    Returns ``{node name: {dotted name: value}}``; keys may carry a namespace or
    wildcards as rcl allows (:func:`node_of_key`); ``/**`` (all nodes) is kept
    as the key ``'/**'``. Raises ReplayError when the file is missing or malformed.
    """
    if path is None:
        return {}
    import yaml

    from robot_calib.io.safe_yaml import load_yaml
    p = Path(path)
    if not p.is_file():
        raise ReplayError(f'parameter file not found: {p} (expected a YAML file like '
                          'config/robot_calib.yaml)')
    try:
        data = load_yaml(p)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        first = ' '.join(str(exc).split())
        raise ReplayError(f'cannot read parameter file {p}: {first}') from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ReplayError(f'parameter file {p}: expected a mapping of node names to '
                          '{ros__parameters: {...}}')
    out: dict[str, dict[str, Any]] = {}
    for node, section in data.items():
        if not isinstance(section, dict) or not isinstance(
                section.get('ros__parameters', {}), dict) or \
                (section and 'ros__parameters' not in section):
            found = f' (found {sorted(map(str, section))})' if isinstance(section, dict) else ''
            raise ReplayError(f'parameter file {p}: node {node!r} must map to '
                              f'{{ros__parameters: {{...}}}}{found}')
        name = node_of_key(node)
        # a section for another package's node is fine (one file may serve a whole robot);
        # one a letter or two away from ours is a typo that would silently do nothing
        close = difflib.get_close_matches(name, list(methods.REGISTRY), 1, 0.85)
        if close and close[0] != name:
            raise ReplayError(f'parameter file {p}: node {node!r} is not a node of ours; '
                              f'did you mean {close[0]!r}?')
        flat = flatten_nested(section.get('ros__parameters') or {})
        # parameters of the live node only (where it writes, the ROS clock): nothing to set
        # offline, so the file a live node reads serves a replay as it is
        flat = {k: v for k, v in flat.items() if k not in NODE_ONLY}
        out.setdefault(name, {}).update(flat)
    return out


NODE_ONLY = ('output_dir', 'use_sim_time')
"""Parameters a live node has besides its method's (ignored by replay)."""


def check_override_nodes(by_node: dict[str, Any], names: set[str]) -> None:
    """Raise ReplayError for ``--set`` items of nodes that are not run (they would do nothing)."""
    for node in by_node:
        if node not in names:
            raise ReplayError(f'--set {node}.*: {node} is not among the nodes run '
                              f'({", ".join(sorted(names))})')


def _node_name(cls: type) -> str:
    return getattr(cls, 'name', '') or cls.__name__


def resolve_node(spec: NodeSpec) -> tuple[str, type]:
    """Return ``(name, pipeline class)`` of a registry name, ``module:Class`` or a class."""
    if isinstance(spec, type):
        cls = spec
    elif ':' in spec:
        module, _, attr = spec.partition(':')
        try:
            mod = importlib.import_module(module)
        except ImportError as exc:
            raise ReplayError(f'--nodes {spec}: cannot import module {module!r} ({exc})') \
                from None
        cls = getattr(mod, attr, None)
        if cls is None:
            raise ReplayError(f'--nodes {spec}: module {module!r} has no class {attr!r}')
    else:
        if spec not in methods.REGISTRY:
            raise ReplayError(f'unknown node {spec!r}; expected one of '
                              f'{", ".join(methods.REGISTRY)} or package.module:Class')
        if spec not in methods.available():
            raise ReplayError(f'node {spec!r} is not available in this installation '
                              f'(available: {", ".join(methods.available()) or "none"})')
        try:
            cls = methods.load(spec)
        except Exception as exc:  # noqa: B902 - a broken module is reported, not raised
            raise ReplayError(f'node {spec!r} cannot be loaded: {type(exc).__name__}: '
                              f'{" ".join(str(exc).split())}') from None
    if not (isinstance(cls, type) and issubclass(cls, Pipeline)):
        raise ReplayError(f'--nodes {spec}: {cls!r} is not a robot_calib Pipeline class')
    return _node_name(cls), cls


def params_for(name: str, cls: type, file_params: dict[str, dict[str, Any]],
               overrides: dict[str, Any]) -> Any:
    """Return node ``name``'s params: defaults, the file's ``/**`` and node keys, ``--set``."""
    params_type = cls.params_type
    if not dataclasses.is_dataclass(params_type):
        if file_params.get(name) or overrides:
            raise ReplayError(f'node {name} has no parameters to set')
        return None
    known = {i.name for i in describe(params_type)}
    flat = {k: v for k, v in file_params.get('/**', {}).items() if k in known}
    flat.update(file_params.get(name, {}))
    flat.update(overrides)
    try:
        return from_flat(params_type, flat)
    except ParamError as exc:
        raise ParamError(f'node {name}: {exc}') from None


def check_out_dir(out_dir: Path) -> None:
    """Raise ReplayError when ``out_dir`` cannot be (re)placed by a replay output."""
    if out_dir.exists() and not out_dir.is_dir():
        raise ReplayError(f'output {out_dir} exists and is not a folder; expected a folder path')
    if out_dir.is_dir() and any(out_dir.iterdir()) and not (out_dir / SUMMARY).is_file():
        raise ReplayError(f'output folder {out_dir} exists, is not empty and is not a '
                          'previous replay output; give a new or empty folder')
    ancestor = out_dir.absolute().parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir() or not os.access(ancestor, os.W_OK | os.X_OK):
        raise ReplayError(f'output folder {out_dir.parent} is not writable ({ancestor} is not '
                          'a writable folder); expected a writable folder')


def check_out_not_input(out_dir: Path, bags: Iterable[Union[str, os.PathLike]]) -> None:
    """
    Raise ReplayError when ``out_dir`` is, contains or lies inside one of the input ``bags``.

    A replay replaces its output folder, so ``replay X --out X`` (X an earlier
    replay's output, itself a bag) would destroy its own input. Symbolic links
    are resolved on both sides.
    """
    out = Path(out_dir).resolve()
    for bag in bags:
        path = Path(bag).resolve()
        if out == path or out in path.parents:
            where = 'is' if out == path else 'contains'
        elif path in out.parents:
            where = 'is inside'
        else:
            continue
        raise ReplayError(f'output folder {out_dir} {where} the input bag {bag}: the replay '
                          'would replace its own input; give another output folder')


def prepare_out_dir(out_dir: Path) -> Path:
    """Check the output folder and return a fresh temporary folder next to it."""
    check_out_dir(out_dir)
    parent = out_dir.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f'.{out_dir.name}.partial-', dir=parent))
        umask = os.umask(0o022)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)  # a normal folder once in place (mkdtemp makes 0700)
        return tmp
    except OSError as exc:
        raise ReplayError(f'output folder {parent} is not writable '
                          f'({exc.strerror or exc}); expected a writable folder') from None


def move_into_place(tmp: Path, out_dir: Path) -> None:
    """Replace ``out_dir`` (a previous output, if any) with the finished folder ``tmp``."""
    old = None
    if out_dir.exists():
        old = Path(tempfile.mkdtemp(prefix=f'.{out_dir.name}.old-', dir=out_dir.parent))
        os.replace(out_dir, old / 'previous')
    os.replace(tmp, out_dir)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
