# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Read user-supplied YAML safely: bounded size, nesting depth, node count and alias expansion.

``yaml.safe_load`` refuses unsafe tags but not absurd shapes: a 1 KB file of
nested anchors ("billion laughs") composes into a graph whose aliases expand to
billions of nodes once walked (replay grew to 5 GB before a MemoryError), and a
file nested 100,000 deep ends in a RecursionError. :func:`load_yaml` first
walks the parser's event stream (no recursion, no objects built), counting the
nodes the document would have with every alias expanded and its depth, and
refuses at the first limit passed; only then is the document constructed.

Every YAML a user hands us goes through here: ``--params`` files (replay,
fleet, a fleet manifest row's ``params``), fleet manifests and a ROS 2 bag's
``metadata.yaml``. A refusal is a :class:`YamlLimitError`, a ``yaml.YAMLError``
whose message is one line, so callers report it as they report a syntax error.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Union

import yaml

MAX_BYTES = 16 * 2**20
"""Largest YAML file read (bytes): a parameter file or manifest is far smaller."""
MAX_DEPTH = 64
"""Deepest nesting of mappings and sequences accepted (ROS 2 parameter files use < 10)."""
MAX_NODES = 1_000_000
"""Most nodes accepted, counted with every alias expanded (about 100,000 manifest rows)."""

_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


class YamlLimitError(yaml.YAMLError):
    """A YAML document refused for its size, depth or alias expansion (one-line message)."""


def check_yaml_text(text: str, *, max_depth: int = MAX_DEPTH,
                    max_nodes: int = MAX_NODES) -> None:
    """
    Raise :class:`YamlLimitError` when ``text`` nests or expands beyond the limits.

    One pass over the parser's events: a collection's size is itself plus its
    contents, an alias counts the size of the node its anchor names, and the
    sum over the document is the number of nodes a consumer walking the
    constructed data would visit. Syntax errors are left to the loader.

    :param text: the YAML document.
    :param max_depth: deepest nesting accepted (mappings and sequences).
    :param max_nodes: most nodes accepted with aliases expanded.
    """
    stack: list[list] = []  # [size so far, anchor] of each open collection
    sizes: dict[str, int] = {}
    total = 0
    try:
        for event in yaml.parse(text, Loader=_LOADER):
            if isinstance(event, (yaml.ScalarEvent, yaml.AliasEvent)):
                if isinstance(event, yaml.AliasEvent):
                    size = sizes.get(event.anchor, 1)
                else:
                    size = 1
                    if event.anchor is not None:
                        sizes[event.anchor] = 1
                total += size
                if stack:
                    stack[-1][0] += size
            elif isinstance(event, yaml.CollectionStartEvent):
                if len(stack) >= max_depth:
                    raise YamlLimitError(f'nested deeper than {max_depth} levels: refused')
                total += 1
                stack.append([1, event.anchor])
            elif isinstance(event, yaml.CollectionEndEvent) and stack:
                size, anchor = stack.pop()
                if anchor is not None:
                    sizes[anchor] = size
                if stack:
                    stack[-1][0] += size
            if total > max_nodes:
                raise YamlLimitError(
                    f'its aliases expand to more than {max_nodes} nodes: refused (nested '
                    'anchors like these are a "billion laughs" bomb)'
                    if sizes else f'more than {max_nodes} nodes: refused')
    except RecursionError:
        raise YamlLimitError(f'nested deeper than {max_depth} levels: refused') from None


def load_yaml(path: Union[str, os.PathLike], *, max_bytes: int = MAX_BYTES,
              max_depth: int = MAX_DEPTH, max_nodes: int = MAX_NODES) -> Any:
    """
    Return the data of the YAML file ``path`` (safe tags only), refusing hostile shapes.

    Raises OSError or UnicodeDecodeError when the file cannot be read as text,
    ``yaml.YAMLError`` when it does not parse, and :class:`YamlLimitError` (a
    ``yaml.YAMLError``) when it is larger than ``max_bytes`` bytes, nests deeper
    than ``max_depth`` or has more than ``max_nodes`` nodes with aliases expanded.

    :param path: the file.
    :param max_bytes: largest file read (bytes).
    :param max_depth: deepest nesting accepted.
    :param max_nodes: most nodes accepted with aliases expanded.
    """
    text = check_yaml_file(path, max_bytes=max_bytes, max_depth=max_depth,
                           max_nodes=max_nodes)
    return yaml.load(text, Loader=_LOADER)  # noqa: S506 - a safe loader


def check_yaml_file(path: Union[str, os.PathLike], *, max_bytes: int = MAX_BYTES,
                    max_depth: int = MAX_DEPTH, max_nodes: int = MAX_NODES) -> str:
    """
    Return the text of the YAML file ``path`` once checked; raise as :func:`load_yaml`.

    Nothing is constructed: for a file another library then reads (a bag's
    ``metadata.yaml``).

    :param path: the file.
    :param max_bytes: largest file read (bytes).
    :param max_depth: deepest nesting accepted.
    :param max_nodes: most nodes accepted with aliases expanded.
    """
    with open(Path(path), 'rb') as f:
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise YamlLimitError(f'larger than {max_bytes // 2**20} MiB: refused')
    text = data.decode('utf-8')
    check_yaml_text(text, max_depth=max_depth, max_nodes=max_nodes)
    return text
