# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
One bag through the replay code, as a job a worker process runs; rows for the fleet table.

Each bag's replay output goes to ``DIR/bags/<robot>/<bag name>/`` (written into
place atomically by replay) with a ``fleet.json`` beside it: the fingerprint of
the code version and parameters it was made with, what the bag was (its resolved
path and a digest of its contents, :func:`bag_identity`) and its rows. A bag
whose ``fleet.json`` has the same fingerprint and the same bag is not replayed
again (a resumed run); a bag whose path or contents changed is replayed again,
and said. A failing bag gives ``failed`` rows with its one-line reason and never
stops the others; a full disk stops the run (:class:`DiskFull`).
"""

from __future__ import annotations

from dataclasses import dataclass
import datetime
import errno
import gc
import hashlib
import json
import os
from pathlib import Path
import resource
import shutil
import time
from typing import Any, Optional

from robot_calib import __version__, methods
from robot_calib.fleet.source import FleetError, Job

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


SAMPLE_BYTES = 1 << 20
"""Bytes read from each end of a bag file for its content digest (the rest: size and mtime)."""
SCRATCH = ('-wal', '-shm', '-journal')
"""Files a database reader may create beside a sqlite3 bag: not part of the bag."""


def _sample(h: Any, path: Path, size: int) -> None:
    """Feed ``h`` the first and the last :data:`SAMPLE_BYTES` of ``path``."""
    with open(path, 'rb') as f:
        h.update(f.read(SAMPLE_BYTES))
        if size > SAMPLE_BYTES:
            f.seek(max(SAMPLE_BYTES, size - SAMPLE_BYTES))
            h.update(f.read(SAMPLE_BYTES))


def bag_identity(bag: Path) -> dict[str, str]:
    """
    Return what identifies a bag: its resolved path and a cheap digest of its contents.

    The digest covers every file's name, size and modification time, the whole
    ``metadata.yaml`` and the first and last MB of the first and last data file:
    a few MB read whatever the bag's size. A bag replaced by another recording
    (even one copied with its times kept) or rewritten in place gets another.
    """
    path = Path(bag).resolve()
    h = hashlib.sha256()
    if path.is_dir():
        files = sorted(p for p in path.rglob('*') if p.is_file()
                       and not p.name.endswith(SCRATCH))
    else:
        files = [path]
    data = []
    for file in files:
        st = file.stat()
        name = str(file.relative_to(path)) if file != path else file.name
        h.update(f'{name}\0{st.st_size}\0{st.st_mtime_ns}\0'.encode())
        if file.name == 'metadata.yaml' and file.parent == path:
            h.update(file.read_bytes()[:16 * SAMPLE_BYTES])
        else:
            data.append((file, st.st_size))
    for file, size in dict.fromkeys(data[:1] + data[-1:]):
        _sample(h, file, size)
    return {'path': str(path), 'content': h.hexdigest()[:16]}


class DiskFull(FleetError):
    """No space left on the device of the output folder: an environment error, the run stops."""


def disk_full(exc: BaseException) -> bool:
    """Return whether ``exc`` (or what it came from) is a full disk or an exceeded quota."""
    codes = {errno.ENOSPC, errno.EDQUOT}
    texts = [os.strerror(c) for c in codes]
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OSError) and exc.errno in codes:
            return True
        if any(t in str(exc) for t in texts):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


def disk_full_error(out: Path) -> DiskFull:
    """Return the one-line error of a full disk under the output folder ``out``."""
    return DiskFull(f'no space left on the device of {out}: free space and run the same '
                    'command again (the bags done so far are kept and reused)')


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
        cls = methods.load(node)
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
    """Replay one bag (unless done with the same fingerprint and bag); return its rows."""
    return run_noted(job, settings)[0]


def _changed(old: Any, new: dict[str, str]) -> str:
    """Return how the bag done before differs from ``new`` (empty when it is the same)."""
    if not isinstance(old, dict):
        return 'not known to be this bag (done by an earlier version)'
    if old.get('path') != new['path']:
        return f'another recording: was {old.get("path")}, now {new["path"]}'
    if old.get('content') != new['content']:
        return 'its contents changed in place'
    return ''


def run_noted(job: Job, settings: Settings) -> tuple[list[dict[str, Any]], str]:
    """
    Replay one bag (unless done with the same fingerprint and bag); return its rows and a note.

    The note is empty, or says that the bag done there before was another one
    (another path, or contents changed in place) and was replayed again. A full
    disk raises :class:`DiskFull` (nothing half-written is left).
    """
    from robot_calib.replay import replay
    out = settings.out / 'bags' / job.robot / job.name
    stamp = fingerprint(settings, job)
    done = out / FLEET_FILE
    try:
        identity: Optional[dict[str, str]] = bag_identity(job.bag)
    except OSError:
        identity = None   # gone or unreadable: not reused, the replay says what is wrong
    note = ''
    if identity is not None and done.is_file() and not settings.force:
        try:
            record = json.loads(done.read_text())
            if record.get('fingerprint') == stamp:
                why = _changed(record.get('bag'), identity)
                if not why:
                    return record['rows'], ''
                note = f'{job.robot}/{job.name} changed since it was done ({why}): replayed again'
                shutil.rmtree(out)   # nothing of the other bag may stay, even if this one fails
        except (OSError, ValueError, KeyError, AttributeError):
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
        if disk_full(exc):
            raise disk_full_error(settings.out) from None
        return failed_rows(job, f'{type(exc).__name__}: {" ".join(str(exc).split())}'[:300],
                           time.perf_counter() - t0, peak_rss_mb()), note
    tmp = done.with_suffix('.tmp')
    try:
        tmp.write_text(json.dumps({'fingerprint': stamp, 'bag': identity, 'rows': rows},
                                  allow_nan=False, default=str))
        os.replace(tmp, done)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        if disk_full(exc):
            raise disk_full_error(settings.out) from None
        raise
    return rows, note
