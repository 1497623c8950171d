# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Standing warnings a method has about its inputs, said once in summary.json and on /diagnostics.

A sensor frame missing from ``/tf_static`` (:func:`robot_calib.core.frames.find_mounting`),
an odometry that fills only its twist (:class:`robot_calib.core.odometry_twist.TwistOnly`):
what the method then does is not an error of one message but a fact about the
recording, kept here by topic so that a later, better answer replaces it.
"""

from __future__ import annotations


class InputNotes:
    """Warnings about the inputs by key (a sensor frame, an input); ``version`` counts changes."""

    def __init__(self) -> None:
        """Start with nothing to say."""
        self.by_key: dict[str, str] = {}
        self.version = 0

    def say(self, key: str, message: str) -> None:
        """Say ``message`` about ``key`` (an empty message takes back what was said)."""
        if message:
            if self.by_key.get(key) != message:
                self.by_key[key] = message
                self.version += 1
        elif self.by_key.pop(key, None) is not None:
            self.version += 1

    def messages(self) -> list[str]:
        """Return the warnings, in the order their keys were first said."""
        return list(self.by_key.values())
