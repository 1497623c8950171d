# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Registry of the method pipelines by executable name, derived from the method folders."""

from __future__ import annotations

import importlib
import importlib.util

from robot_calib import methods

REGISTRY = {name: methods.pipeline_target(name) for name in methods.names()}
"""Executable name -> ``module:attribute`` of its pipeline class (imported lazily)."""


def available() -> list[str]:
    """Return the names of the pipelines whose modules are present, in registry order."""
    names = []
    for name, target in REGISTRY.items():
        module = target.split(':')[0]
        if importlib.util.find_spec(module) is not None:
            names.append(name)
    return names


def load(name: str) -> type:
    """Return the pipeline class of executable ``name``; KeyError when unknown."""
    if name not in REGISTRY:
        raise KeyError(f'unknown node {name!r}; known: {", ".join(REGISTRY)}')
    module, cls = REGISTRY[name].split(':')
    return getattr(importlib.import_module(module), cls)
