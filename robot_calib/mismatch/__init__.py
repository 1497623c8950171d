# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Sim-vs-real mismatch analyser: locate the mismatch, name the missing physics, model it.

``analyse(sim_bag, real_bag, out_dir)`` reads both bags, aligns them
(:mod:`.channels`), measures the noise floor and where the residual leaves it
(:mod:`.locate`), selects the smallest set of effects from the library
(:mod:`.effects`, :mod:`.select`) and writes ``out_dir/findings.json``,
``out_dir/report.md`` and PNG plots (:mod:`.report`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Optional

from robot_calib.mismatch.analysis import analyse_recordings, MismatchParams
from robot_calib.mismatch.channels import ChannelError, read_bag

__all__ = ['MismatchError', 'MismatchParams', 'analyse', 'analyse_recordings', 'read_bag']


class MismatchError(ValueError):
    """Input the analyser cannot judge at all (one-line message)."""


def analyse(sim_bag: os.PathLike | str, real_bag: os.PathLike | str,
            out_dir: os.PathLike | str, params: Optional[MismatchParams] = None,
            plots: bool = True) -> dict:
    """
    Compare a simulated and a real recording of the same run; write findings and a report.

    :param sim_bag: the simulated bag (ROS 2 folder or ROS 1 file)
    :param real_bag: the real bag
    :param out_dir: output folder (created); receives findings.json, report.md and PNGs
    :param params: analyser parameters (defaults: :class:`MismatchParams`)
    :param plots: write the PNG plots
    :returns: the findings dict (contract schema plus additive keys)
    :raises MismatchError: on input that cannot be compared (one-line message)
    """
    from robot_calib.mismatch import report
    for name, p in (('sim', sim_bag), ('real', real_bag)):
        if not Path(p).exists():
            raise MismatchError(f'{name} bag not found: {p}')
    try:
        sim = read_bag(sim_bag)
        real = read_bag(real_bag)
        if not sim:
            raise MismatchError(f'the simulated bag {sim_bag} has no IMU, odometry or command '
                                'topic')
        if not real:
            raise MismatchError(f'the real bag {real_bag} has no IMU, odometry or command topic')
        findings, details = analyse_recordings(sim, real, params)
    except ChannelError as exc:
        raise MismatchError(str(exc).splitlines()[0]) from None
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise MismatchError(f'cannot create the output folder {out}: {exc}') from None
    findings['inputs'] = {'sim': str(sim_bag), 'real': str(real_bag)}
    report.write(out, findings, details, plots=plots)
    return findings
