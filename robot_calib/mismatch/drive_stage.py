# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The drive chain in the analyser's time step (:mod:`.drive` fits it).

On a drive, a late speed or turn rate is first the drive's response: the
chain is fitted on the clock delays only (those no drive makes), and when it
names dynamics it takes over the time stage's delays of the fields it models
(their dead time is the drive's). A delay alone stays the time stage's
``time_offset``; a dead time the time stage showed at full rate is kept in
the chain, which judges what the dynamics add to it.
"""

from __future__ import annotations

from dataclasses import replace

from robot_calib.mismatch import timing
from robot_calib.mismatch.channels import PairedTopic
from robot_calib.mismatch.drive import analyse_drive, driven, DriveResult, V


def clock_taus(taus: dict) -> dict:
    """Return the delays (s) of ``taus`` no drive can make: any but a late speed, turn or wheel."""
    return {f: t for f, t in taus.items() if not (driven(f) and t > 0)}


def over_delays(prm, taus: dict):
    """Return ``prm`` with the dead time searched past the time stage's delays of speed, turn."""
    late = [t for f, t in taus.items() if driven(f) and t > 0]
    if not late or max(late) + 0.1 <= prm.drive_max_dead_time:
        return prm
    return replace(prm, drive_max_dead_time=max(late) + 0.1)


def taken(drive: DriveResult) -> set:
    """Return the fields whose drive model names a part (their sim is the chain's output)."""
    return {f for f, m in drive.models.items() if m.parts}


def drop_delays(name: str, drive: DriveResult, delays: list, findings: list,
                taus: dict) -> tuple:
    """
    Return (delays, findings, taus) without the late speed or turn rate the drive explains.

    A speed or turn rate that is late on a drive is its response (a dead time
    and a lag) unless the drive chain names nothing but a delay; then the time
    stage's clock delay stands. A delay shared with fields the drive does not
    model stays.
    """
    mine = taken(drive)
    drive.sim = {f: x for f, x in drive.sim.items() if f in mine}
    gone = [(k, te, i) for k, te, i in delays if te.delay.tau > 0 and set(te.fields) <= mine]
    chans = {f'{name}.{f}' for _, te, _ in gone for f in te.fields}
    keep = [f for f in findings if not (f['effect'] in ('time_offset', 'timing_drift',
                                                        'drive_lag') and
                                        chans & set(f.get('channels', [f['channel']])))]
    left = {f: t for f, t in taus.items() if f not in mine or f in clock_taus(taus)}
    return [d for d in delays if d not in gone], keep, left


def drive_stage(pt: PairedTopic, prm, taus: dict, delays: list, findings: list,
                acmd_at) -> tuple:
    """
    Return (drive or None, delays, findings, taus) of an odometry topic after its time stage.

    The chain is fitted on the clock delays (``taus`` no drive makes): a late
    speed or turn rate is the drive's response, so when the chain names
    dynamics the time stage's delays of the fields it models go (their dead
    time is the drive's). When it names nothing beyond a delay, the time
    stage's delays stand and the chain is tried once more behind them.
    ``acmd_at(topic, tau)``: the commanded acceleration on the topic's grid.
    """
    clock = clock_taus(taus)
    pre = timing.aligned(pt, clock)
    drive = analyse_drive(pre, over_delays(prm, taus), acmd_at(pre, clock.get(V, 0.0)),
                          frozenset(f for f in taus if f not in clock))
    if drive is not None and clock != taus:
        delays, findings, taus = drop_delays(pt.name, drive, delays, findings, taus)
    elif drive is None and clock != taus:
        post = timing.aligned(pt, taus)
        drive = analyse_drive(post, prm, acmd_at(post, taus.get(V, 0.0)))
    return drive, delays, findings, taus
