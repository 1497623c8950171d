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

import json
import os
from pathlib import Path
import shutil
import tempfile
from typing import Optional

from robot_calib.mismatch import coverage, export, lidar, trajectory
from robot_calib.mismatch.analysis import analyse_recordings, MismatchParams
from robot_calib.mismatch.channels import ChannelError, read_bag

__all__ = ['MismatchError', 'MismatchParams', 'analyse', 'analyse_recordings', 'read_bag']


class MismatchError(ValueError):
    """Input the analyser cannot judge at all (one-line message)."""


def analyse(sim_bag: os.PathLike | str, real_bag: os.PathLike | str,
            out_dir: os.PathLike | str, params: Optional[MismatchParams] = None,
            plots: bool = True, remaps: Optional[list] = None,
            corrected: os.PathLike | str | None = None) -> dict:
    """
    Compare a simulated and a real recording of the same run; write findings and a report.

    :param sim_bag: the simulated bag (ROS 2 folder or ROS 1 file)
    :param real_bag: the real bag
    :param out_dir: output folder (created); receives findings.json, report.md and PNGs
    :param params: analyser parameters (defaults: :class:`MismatchParams`)
    :param plots: write the PNG plots
    :param remaps: ``[(sim topic, real topic)]`` the user paired (``--remap``)
    :param corrected: a simulation with the findings applied (``simulate follow --params
        sim_params.yaml``): its trajectory joins the report's, with its drift
    :returns: the findings dict (contract schema plus additive keys)
    :raises MismatchError: on input that cannot be compared (one-line message)
    """
    from robot_calib.mismatch import report
    for name, p in (('sim', sim_bag), ('real', real_bag), ('corrected', corrected)):
        if p is not None and not Path(p).exists():
            raise MismatchError(f'{name} bag not found: {p}')
    try:
        sim = read_bag(sim_bag)
        real = read_bag(real_bag)
        if not sim:
            raise MismatchError(f'the simulated bag {sim_bag} has no IMU, odometry or command '
                                'topic')
        if not real:
            raise MismatchError(f'the real bag {real_bag} has no IMU, odometry or command topic')
        findings, details = analyse_recordings(sim, real, params, remaps)
        lidar.merge_into(findings, sim_bag, real_bag, sim, real)
        coverage.list_unjudged(findings, sim_bag, real_bag)
    except ChannelError as exc:
        raise MismatchError(str(exc).splitlines()[0]) from None
    out = Path(out_dir)
    tmp = _partial_folder(out)
    try:
        findings['inputs'] = {'sim': str(sim_bag), 'real': str(real_bag)}
        if corrected is not None:
            findings['inputs']['corrected'] = str(corrected)
        traj = _trajectories(sim_bag, real_bag, corrected, findings)
        if traj is not None:
            findings['trajectory'] = trajectory.summary(traj)
            if plots:
                findings['trajectory']['plot'] = trajectory.plot(tmp, traj)
        report.write(tmp, findings, details, plots=plots)
        export.write(tmp, json.loads((tmp / 'findings.json').read_text()), str(sim_bag))
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return findings


def _trajectories(sim_bag, real_bag, corrected, findings: dict) -> Optional[dict]:
    """Return the trajectory comparison of the bags, or None when they share no odometry."""
    clock = (findings.get('time_alignment') or {}).get('clock') or {}
    offset = float(clock.get('offset') or 0.0)
    try:
        return trajectory.compare(str(sim_bag), str(real_bag),
                                  str(corrected) if corrected is not None else None, offset)
    except (ValueError, KeyError, IndexError, OSError) as exc:
        findings.setdefault('notes', []).append(f'no trajectory comparison: {exc}')
        return None


def _partial_folder(out: Path) -> Path:
    """Return a fresh hidden folder next to ``out``; MismatchError when it cannot be written."""
    if out.exists() and not out.is_dir():
        raise MismatchError(f'output {out} exists and is not a folder; expected a folder path')
    if out.is_dir() and any(out.iterdir()) and not (out / 'findings.json').is_file():
        raise MismatchError(f'output folder {out} exists, is not empty and is not a previous '
                            'mismatch output; give a new or empty folder')
    try:
        out.absolute().parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f'.{out.name}.partial-', dir=out.absolute().parent))
        os.chmod(tmp, 0o755)
        return tmp
    except OSError as exc:
        raise MismatchError(f'cannot write the output folder {out}: '
                            f'{exc.strerror or exc}') from None
