# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
What bag reading and bag writing share: :class:`BagError`, topic names, one-line messages.

Kept apart so that :mod:`robot_calib.io.bags` (reading) can re-export
:mod:`robot_calib.io.bag_writer` (writing) without an import cycle; both
:class:`BagError` and :func:`normalize_topic` are importable from ``bags``.
"""

from __future__ import annotations


class BagError(RuntimeError):
    """A bag that is missing, unreadable or not what was expected (one-line message)."""


def normalize_topic(topic: str) -> str:
    """Return ``topic`` with exactly one leading slash."""
    return '/' + topic.lstrip('/')


def one_line(exc: BaseException) -> str:
    """Return the message of ``exc`` on one line (its type name when it has none)."""
    text = ' '.join(str(exc).split())
    return text or type(exc).__name__
