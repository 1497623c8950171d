# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Every topic of either bag is compared or listed under ``not_judged`` with a reason."""

from __future__ import annotations

import os

__all__ = ['list_unjudged']


def _covered(findings: dict) -> set:
    seen = set()
    for key in ('channels', 'time_alignment'):
        for name in findings.get(key) or {}:
            seen.add(name)
    for d in findings.get('not_judged') or []:
        seen.add(str(d.get('channel', '')))
    for f in findings.get('findings') or []:
        seen.add(str(f.get('channel', '')))
    seen.update((findings.get('lidar') or {}).get('judged', []))
    return seen


def list_unjudged(findings: dict, sim_bag: os.PathLike | str,
                  real_bag: os.PathLike | str) -> None:
    """Add to ``findings['not_judged']`` each topic of the bags that nothing compared."""
    from robot_calib.io import bags
    seen = _covered(findings)
    nj = findings.setdefault('not_judged', [])
    topics: dict = {}
    for side, path in (('simulated', sim_bag), ('real', real_bag)):
        try:
            for name, (typ, _) in bags.list_topics([path]).items():
                topics.setdefault(name, (typ, []))[1].append(side)
        except (bags.BagError, OSError, ValueError):
            continue
    for name, (typ, sides) in sorted(topics.items()):
        if any(s == name or s.startswith(name + '.') for s in seen):
            continue
        where = 'both recordings' if len(sides) == 2 else f'the {sides[0]} recording only'
        nj.append({'channel': name, 'reason': f'{typ} (in {where}) is not compared by the '
                   'analyser'})
