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

The registry of the method pipelines lives here too (:data:`REGISTRY`,
:func:`available`, :func:`load`): names map to ``module:attribute`` strings,
imported only when asked for, so importing a method never imports a pipeline.
"""

from __future__ import annotations

import importlib
import importlib.util
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


REGISTRY = {name: pipeline_target(name) for name in names()}
"""Executable name -> ``module:attribute`` of its pipeline class (imported lazily)."""


def available() -> list[str]:
    """Return the names of the pipelines whose modules are present, in registry order."""
    found = []
    for name, target in REGISTRY.items():
        module = target.split(':')[0]
        if importlib.util.find_spec(module) is not None:
            found.append(name)
    return found


def load(name: str) -> type:
    """Return the pipeline class of executable ``name``; KeyError when unknown."""
    if name not in REGISTRY:
        raise KeyError(f'unknown node {name!r}; known: {", ".join(REGISTRY)}')
    module, cls = REGISTRY[name].split(':')
    return getattr(importlib.import_module(module), cls)
