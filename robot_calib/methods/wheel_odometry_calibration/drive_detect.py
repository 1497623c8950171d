# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The drive type of a robot, told by the joints its ``joint_states`` carry.

A steered drive wheel (tricycle AGV) publishes a steering joint and a traction
joint; a differential drive a left and a right wheel joint. The configured
joint names are tried first; when ``drive_type`` is ``auto`` and they are
absent, joint names are read for their meaning (``steer``; ``left``/``right``
with ``wheel``; ``traction``/``drive``/``wheel``). A steering joint decides for
the steered wheel: a differential robot has none. Anything that does not name
exactly one drive's joints is left undecided, with the reason, so that no
drive type is ever guessed.
"""

from __future__ import annotations

from dataclasses import dataclass
import re
from typing import Iterable, Optional

STEERED = 'steered_wheel'
DIFFERENTIAL = 'differential'


@dataclass(frozen=True)
class DriveJoints:
    """A drive type and its two joints: (left, right) or (traction, steering)."""

    drive_type: str
    joints: tuple[str, str]
    how: str
    """How it was told: 'configured joint names' or 'joint names'."""


@dataclass(frozen=True)
class JointNames:
    """The configured joint names of both drive types."""

    left: str
    right: str
    traction: str
    steering: str

    def configured(self, drive_type: str) -> tuple[str, str]:
        """Return the configured joints of ``drive_type`` in the calibrator's order."""
        return (self.left, self.right) if drive_type == DIFFERENTIAL else \
            (self.traction, self.steering)


def _words(name: str) -> set[str]:
    """Return the lower-case words of a joint name (split at _, -, /, . and case changes)."""
    spaced = re.sub(r'([a-z0-9])([A-Z])', r'\1 \2', name)
    return {w for w in re.split(r'[^a-zA-Z0-9]+', spaced.lower()) if w}


def _is_left(words: set[str]) -> bool:
    return bool(words & {'left', 'l', 'lw'})


def _is_right(words: set[str]) -> bool:
    return bool(words & {'right', 'r', 'rw'})


def by_configured_names(names: Iterable[str], configured: JointNames) -> list[DriveJoints]:
    """Return every drive whose configured joints are all among ``names``."""
    present = set(names)
    out = []
    for drive in (STEERED, DIFFERENTIAL):
        joints = configured.configured(drive)
        if all(j in present for j in joints):
            out.append(DriveJoints(drive, joints, 'configured joint names'))
    return out


def by_meaning(names: Iterable[str]) -> tuple[Optional[DriveJoints], str]:
    """
    Return the drive told by what the joint names say, or (None, why not).

    Steered wheel: exactly one joint named ``steer...`` and exactly one other
    joint named ``traction``/``drive``/``wheel`` that is neither left nor right.
    Differential: no steering joint, exactly one left and one right wheel joint.
    """
    names = list(dict.fromkeys(names))
    words = {n: _words(n) for n in names}
    steer = [n for n in names if any(w.startswith('steer') for w in words[n])]
    wheels = [n for n in names if n not in steer and 'caster' not in words[n] and
              words[n] & {'wheel', 'traction', 'drive'}]
    if len(steer) > 1:
        return None, f'several steering joints ({", ".join(steer)})'
    if steer:
        centre = [n for n in wheels if not (_is_left(words[n]) or _is_right(words[n]))]
        if len(centre) == 1:
            return DriveJoints(STEERED, (centre[0], steer[0]), 'joint names'), ''
        return None, (f'a steering joint ({steer[0]}) but not exactly one traction joint '
                      f'(candidates: {", ".join(centre) or "none"})')
    left = [n for n in wheels if _is_left(words[n]) and not _is_right(words[n])]
    right = [n for n in wheels if _is_right(words[n]) and not _is_left(words[n])]
    if len(left) == 1 and len(right) == 1:
        return DriveJoints(DIFFERENTIAL, (left[0], right[0]), 'joint names'), ''
    if left or right:
        return None, (f'not exactly one left and one right wheel joint (left: '
                      f'{", ".join(left) or "none"}; right: {", ".join(right) or "none"})')
    return None, 'no wheel joints'


def detect(names: Iterable[str], configured: JointNames) -> tuple[Optional[DriveJoints], str]:
    """
    Return the drive the joints ``names`` tell, or (None, why it cannot be told).

    The configured names win; both drives' configured joints present is
    undecidable. Otherwise the joint names are read for their meaning.
    """
    names = list(names)
    found = by_configured_names(names, configured)
    if len(found) == 1:
        return found[0], ''
    if len(found) > 1:
        return None, ('joint_states carry the configured joints of both drive types; set '
                      'drive_type')
    return by_meaning(names)
