# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Which bags a fleet run processes: a folder tree (one subfolder per robot) or a manifest.

A folder SOURCE holds one first-level subfolder per robot, its bags at any depth
(ROS 2 bag folders with ``metadata.yaml``, bare ``.mcap`` files, ROS 1 ``.bag``
files). A manifest (``.csv`` or ``.yaml``) lists rows with ``robot`` and ``bag``
and optionally ``date`` (ISO 8601) and ``params`` (a per-robot parameter file);
relative paths are relative to the manifest.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
import datetime
from pathlib import Path
import re
from typing import Optional

from robot_calib.io.safe_yaml import load_yaml
import yaml


class FleetError(ValueError):
    """A fleet source or argument that cannot be used (one-line message)."""


@dataclass(frozen=True)
class Job:
    """One bag of one robot: where it is, its date if known, its parameter file if any."""

    robot: str
    bag: Path
    date: Optional[str] = None
    params: Optional[Path] = None

    @property
    def name(self) -> str:
        """Return the bag's file or folder name without its suffix (its output folder)."""
        return self.bag.stem if self.bag.is_file() else self.bag.name


def _bags_below(folder: Path) -> list[Path]:
    found = []
    for path in sorted(folder.rglob('*')):
        if any(parent in found for parent in path.parents):
            continue  # inside a bag folder already found
        if path.is_dir() and (path / 'metadata.yaml').is_file():
            found.append(path)
        elif path.is_file() and path.suffix in ('.mcap', '.bag') \
                and not (path.parent / 'metadata.yaml').is_file():
            found.append(path)
    return found


def _from_folder(root: Path, skip: Optional[Path] = None) -> list[Job]:
    robots = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith('.')
                    and (skip is None or p.resolve() != skip))
    return [Job(robot.name, bag) for robot in robots for bag in _bags_below(robot)
            if skip is None or skip not in bag.resolve().parents]  # the output, through a link


COLUMNS = ('robot', 'bag', 'date', 'params')
"""The columns of a fleet manifest (robot and bag required)."""


def _from_manifest(path: Path) -> list[Job]:
    try:
        if path.suffix == '.csv':
            with open(path, newline='') as f:
                rows = list(csv.DictReader(f))
        else:
            rows = load_yaml(path) or []
    except (OSError, UnicodeDecodeError, csv.Error, yaml.YAMLError) as exc:
        raise FleetError(f'cannot read manifest {path}: {" ".join(str(exc).split())}') from None
    if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
        raise FleetError(f'manifest {path}: expected rows with columns robot, bag')
    jobs = []
    for i, row in enumerate(rows, 1):
        unknown = sorted(str(k) for k in row if k not in COLUMNS)
        if unknown:
            # a misspelt column (parms) would silently drop what it was meant to set
            raise FleetError(f'manifest {path} row {i}: unknown column(s) '
                             f'{", ".join(unknown)}; expected {", ".join(COLUMNS)}')
        robot, bag = str(row.get('robot') or '').strip(), str(row.get('bag') or '').strip()
        if not robot or not bag:
            raise FleetError(f'manifest {path} row {i}: robot and bag are required')
        params = str(row.get('params') or '').strip()
        date = str(row.get('date') or '').strip() or None
        if date is not None:
            try:
                datetime.date.fromisoformat(date[:10])
            except ValueError:
                raise FleetError(f'manifest {path} row {i}: date {date!r} is not an ISO date '
                                 '(YYYY-MM-DD); bags are ordered by it') from None
        jobs.append(Job(robot, (path.parent / bag).resolve(), date,
                        (path.parent / params).resolve() if params else None))
    return jobs


def _direct(job: Job, root: Optional[Path]) -> bool:
    """Return whether ``job``'s path reaches its bag through no symbolic link below ``root``."""
    if root is None:
        return True
    path = job.bag
    while path != root and path != path.parent:
        if path.is_symlink():
            return False
        path = path.parent
    return True


def _once(jobs: list[Job], root: Optional[Path], notes: list[str]) -> list[Job]:
    """
    Return ``jobs`` with each bag once, by its resolved path (symbolic links, manifest rows).

    The job kept for a bag reached twice is the one whose path has no symbolic link
    below the source folder (``robot000/day1``, not ``robotlink/day1``), else the
    first; what was dropped is said in ``notes``.
    """
    first: dict[Path, Job] = {}
    for job in sorted(jobs, key=lambda j: not _direct(j, root)):
        first.setdefault(job.bag.resolve(), job)
    kept = [j for j in jobs if first[j.bag.resolve()] is j]
    dropped = [j for j in jobs if first[j.bag.resolve()] is not j]
    if dropped:
        shown = ', '.join(f'{j.robot}/{j.name} (= {first[j.bag.resolve()].robot}/'
                          f'{first[j.bag.resolve()].name})' for j in dropped[:5])
        notes.append(f'{len(dropped)} path(s) led to the same bag as another (symbolic links '
                     f'or repeated manifest rows) and were counted once: {shown}'
                     + (' ...' if len(dropped) > 5 else ''))
    return kept


def _safe_name(name: str) -> bool:
    """Return whether ``name`` stays one folder below its parent (not empty, ``.``, ``..``)."""
    return bool(name) and name.strip('.') != '' and '/' not in name and '\\' not in name \
        and '\0' not in name


def discover(source: Path, out: Optional[Path] = None,
             notes: Optional[list[str]] = None) -> list[Job]:
    """
    Return the jobs of ``source`` (a folder tree or a manifest), robot by robot.

    ``out``: the fleet's output folder, never taken for a robot when it lies
    in ``source`` (a second run would read its own results as bags). Each bag
    is taken once, by its resolved path; ``notes`` receives what was dropped.
    """
    source = Path(source)
    notes = [] if notes is None else notes
    if source.is_dir():
        jobs = _from_folder(source, Path(out).resolve() if out is not None else None)
    elif source.is_file() and source.suffix in ('.csv', '.yaml', '.yml'):
        jobs = _from_manifest(source)
    else:
        raise FleetError(f'fleet source {source} is neither a folder (one subfolder per robot) '
                         'nor a manifest (.csv or .yaml)')
    if not jobs:
        raise FleetError(f'no bags found in {source}')
    bad = sorted({j.robot for j in jobs if not re.fullmatch(r'[\w.-]+', j.robot)
                  or not _safe_name(j.robot)})
    if bad:
        raise FleetError(f'robot names must be letters, digits, _ . - and not only dots: '
                         f'{", ".join(repr(b) for b in bad[:5])}')
    escaping = sorted({str(j.bag) for j in jobs if not _safe_name(j.name)})
    if escaping:
        raise FleetError('bag name(s) made only of dots, whose output folder would lie outside '
                         f'OUT/bags/<robot>/; rename them: {", ".join(escaping[:5])}')
    jobs = _once(jobs, source if source.is_dir() else None, notes)
    names = [(j.robot, j.name) for j in jobs]
    dup = sorted({f'{r}/{n}' for r, n in names if names.count((r, n)) > 1})
    if dup:
        raise FleetError(f'two bags of one robot share a name: {", ".join(dup[:5])}')
    return jobs
