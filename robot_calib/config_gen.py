# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Generate ``config/robot_calib.yaml`` from the params dataclasses (the single source of defaults).

Run ``python -m robot_calib.config_gen > config/robot_calib.yaml``; a test
checks that the committed file is what this prints.
"""

from __future__ import annotations

import math
import sys
from typing import Any

from robot_calib import methods
from robot_calib.core.params import describe
import yaml

HEADER = """\
# robot_calib parameters, one top-level key per node: /**/<executable> matches the node in any
# namespace (a robot's /robot1/tilt_detection too); a renamed node (-r __node:=NAME) needs its
# own key, e.g. /**/NAME. /**: would set a key for every node.
# Load with: ros2 run robot_calib <node> --ros-args --params-file config/robot_calib.yaml
# or replay: robot-calib replay BAG --out DIR --params config/robot_calib.yaml
# Every key: what it is [unit] (default). Generated from the core params dataclasses by
# `python -m robot_calib.config_gen`; edit the dataclasses, not this file.
"""

COMMON = [('output_dir', '.', '', 'folder where the node writes result files at shutdown')]


def _scalar(value: Any) -> str:
    if isinstance(value, float) and math.isfinite(value):
        return repr(value)
    return yaml.safe_dump(value, default_flow_style=True).strip().removesuffix('\n...').strip()


def _emit(lines: list[str], tree: dict, indent: int) -> None:
    pad = ' ' * indent
    for key, value in tree.items():
        if isinstance(value, dict):
            lines.append(f'{pad}{key}:')
            _emit(lines, value, indent + 2)
        else:
            default, unit, doc = value
            unit_txt = f' [{unit}]' if unit else ''
            lines.append(f'{pad}# {doc}{unit_txt} (default {_scalar(default)})')
            lines.append(f'{pad}{key}: {_scalar(default)}')


def node_section(name: str) -> list[str]:
    """Return the YAML lines of one node's ``ros__parameters`` (key ``/**/<name>``)."""
    cls = methods.load(name)
    tree: dict = {}
    for info in describe(cls.params_type):
        node = tree
        parts = info.name.split('.')
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = (info.default, info.unit, info.doc)
    for key, default, unit, doc in COMMON:
        tree.setdefault(key, (default, unit, doc))
    lines = [f'/**/{name}:', '  ros__parameters:']
    _emit(lines, tree, 4)
    return lines


def render() -> str:
    """Return the whole YAML text for every pipeline present."""
    lines = [HEADER.rstrip('\n')]
    for name in methods.available():
        lines.append('')
        lines.extend(node_section(name))
    return '\n'.join(lines) + '\n'


def main() -> int:
    """Print the generated YAML to stdout."""
    sys.stdout.write(render())
    return 0


if __name__ == '__main__':
    sys.exit(main())
