# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
One bag through the replay code, as a job a worker process runs; rows for the fleet table.

Each bag's replay output goes to ``DIR/bags/<robot>/<bag name>/`` (written into
place atomically by replay) with a ``fleet.json`` beside it: the fingerprint of
the code version and parameters it was made with, and its rows. A bag whose
``fleet.json`` has the same fingerprint is not replayed again (a resumed run);
a failing bag gives ``failed`` rows with its one-line reason and never stops
the others.
"""

from __future__ import annotations

from dataclasses import dataclass
import datetime
import gc
import hashlib
import json
import os
from pathlib import Path
import resource
import time
from typing import Any, Optional

from robot_calib import __version__, pipelines
from robot_calib.fleet.source import Job

FLEET_FILE = 'fleet.json'
ROW_FORMAT = 2
"""Format of the rows kept in ``fleet.json`` (2: ``corrupt_chunks``); other formats are redone."""


@dataclass(frozen=True)
class Settings:
    """What every job of one fleet run shares."""

    out: Path
    nodes: Optional[tuple[str, ...]]
    params_file: Optional[Path]
    overrides: tuple[str, ...]
    force: bool
    plots: bool = False


def fingerprint(settings: Settings, job: Job) -> str:
    """Return a digest of what determines a bag's rows: code and row version, nodes, parameters."""
    h = hashlib.sha256()
    for part in (__version__, str(ROW_FORMAT), repr(settings.nodes), repr(settings.overrides)):
        h.update(part.encode())
    if settings.plots:
        h.update(b'plots')   # a bag done without its plots is redone when they are asked
    for path in (settings.params_file, job.params):
        h.update(path.read_bytes() if path is not None and path.is_file() else b'-')
    return h.hexdigest()[:16]


def _date(job: Job, summary: dict) -> str:
    if job.date:
        return job.date
    start = summary.get('start_time')
    if start is None:
        return ''
    return datetime.datetime.fromtimestamp(start, datetime.timezone.utc).isoformat()


def peak_rss_mb() -> float:
    """Return the peak resident memory of this process so far (MB; all the bags it ran)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _rows(job: Job, summary: dict, seconds: float) -> list[dict[str, Any]]:
    """
    Return one row per node of a finished replay (status ok, or skipped with the reason).

    ``corrupt_chunks``: the mcap chunks replay skipped as corrupt (their messages not used).
    """
    date = _date(job, summary)
    base = {'robot': job.robot, 'date': date, 'bag': str(job.bag), 'peak_rss_mb': peak_rss_mb(),
            'corrupt_chunks': len(summary.get('corrupt_chunks') or ())}
    rows = []
    for node, part in summary.get('nodes', {}).items():
        row = {**base, 'node': node, 'status': 'ok', 'reason': '', 'runtime_s': seconds}
        cls = pipelines.load(node)
        row.update({f'{node}.{k}': v for k, v in cls.headline(part).items()})
        rows.append(row)
    for node, reason in summary.get('skipped', {}).items():
        rows.append({**base, 'node': node, 'status': 'skipped', 'reason': reason,
                     'runtime_s': 0.0})
    return rows


def failed_rows(job: Job, reason: str, seconds: float,
                peak_mb: Optional[float]) -> list[dict[str, Any]]:
    """Return the one ``failed`` row of a bag (``peak_mb``: its worker's peak memory, if known)."""
    return [{'robot': job.robot, 'date': job.date or '', 'bag': str(job.bag), 'node': '',
             'status': 'failed', 'reason': reason, 'runtime_s': seconds, 'peak_rss_mb': peak_mb}]


def run_job(job: Job, settings: Settings) -> list[dict[str, Any]]:
    """Replay one bag (unless done with the same fingerprint); return its rows."""
    from robot_calib.replay import replay
    out = settings.out / 'bags' / job.robot / job.name
    stamp = fingerprint(settings, job)
    done = out / FLEET_FILE
    if done.is_file() and not settings.force:
        try:
            record = json.loads(done.read_text())
            if record.get('fingerprint') == stamp:
                return record['rows']
        except (OSError, ValueError, KeyError):
            pass  # unreadable: redo the bag
    t0 = time.perf_counter()
    try:
        overrides = list(settings.overrides)
        summary = replay([job.bag], out, nodes=list(settings.nodes) if settings.nodes else None,
                         params_file=job.params or settings.params_file,
                         overrides=overrides, progress=False, plots=settings.plots)
        # A replay leaves reference cycles (matplotlib figures and their pixel buffers, the
        # pipelines) that the cyclic collector frees only at its own pace: a worker grew
        # about 20 MB a bag. Freed here, a worker's memory stays that of one bag.
        gc.collect()
        rows = _rows(job, summary, time.perf_counter() - t0)
    except Exception as exc:  # noqa: B902 - any failure of one bag is a failed row
        gc.collect()
        return failed_rows(job, f'{type(exc).__name__}: {" ".join(str(exc).split())}'[:300],
                           time.perf_counter() - t0, peak_rss_mb())
    tmp = done.with_suffix('.tmp')
    tmp.write_text(json.dumps({'fingerprint': stamp, 'rows': rows}, allow_nan=False,
                              default=str))
    os.replace(tmp, done)
    return rows
