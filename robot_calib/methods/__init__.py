# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The five methods, one folder each, found by looking at the folders.

A method folder ``robot_calib/methods/<executable>/`` holds its parameters,
its estimator variants (seed-faithful and improved, same API), the
:class:`~robot_calib.pipelines.base.Pipeline` adapter in ``pipeline.py``
(which names the class it exports as ``PIPELINE``) and the node's ``main`` in
``node.py``. Its ``__init__`` sets ``SEED``, the number of the patent it
reads, which orders the methods everywhere (registry, config, reports).
"""

from __future__ import annotations

import importlib
from pathlib import Path

_HERE = Path(__file__).resolve().parent


def names() -> list[str]:
    """Return the executable names of the method folders, in seed order."""
    found = []
    for folder in _HERE.iterdir():
        if (folder / '__init__.py').is_file() and (folder / 'pipeline.py').is_file():
            package = importlib.import_module(f'{__name__}.{folder.name}')
            found.append((getattr(package, 'SEED', '999'), folder.name))
    return [name for _, name in sorted(found)]


def pipeline_target(name: str) -> str:
    """Return ``module:attribute`` of method ``name``'s pipeline class."""
    return f'{__name__}.{name}.pipeline:PIPELINE'


def node_target(name: str) -> str:
    """Return the console-script target ``module:main`` of method ``name``'s node."""
    return f'{__name__}.{name}.node:main'
