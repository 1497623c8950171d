# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
``robot-calib fleet``: every robot's recordings through the same replay code, in parallel.

:func:`run_fleet` finds the bags (:mod:`~robot_calib.fleet.source`), runs each
through replay (:mod:`~robot_calib.fleet.runner`: resumable, a failing bag never
stops the others) on a local process pool, or on a Ray cluster (``ray``, an
optional extra: ``pip install -r requirements-ray.txt``), and writes the result set
(:mod:`~robot_calib.fleet.results`): ``results.csv`` and ``results.parquet`` (one
row per bag and node), ``flags.csv`` and ``report.md``. The rows do not depend
on the number of workers or on the executor.

One run at a time owns an output folder (:class:`OutputLock`); local workers
end with their parent, even when it is killed (:func:`worker_start`).
"""

from __future__ import annotations

from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
import ctypes
import ctypes.util
import multiprocessing
import os
from pathlib import Path
import shutil
import signal
import sys
import threading
import time
from typing import Any, Callable, Iterable, Iterator, Optional, Union

from robot_calib.fleet import report, results
from robot_calib.fleet.runner import disk_full, disk_full_error, DiskFull, failed_rows, \
    run_noted, Settings
from robot_calib.fleet.source import discover, FleetError, Job

try:
    import fcntl
except ImportError:  # pragma: no cover - not on Linux or macOS: no locks
    fcntl = None

__all__ = ['DiskFull', 'FleetError', 'Job', 'OutputLock', 'run_fleet', 'worker_start']

RUN_LOCK = '.fleet.lock'
"""Held (exclusive) by the fleet run that owns the output folder; holds its pid."""
WORKERS_LOCK = '.fleet-workers.lock'
"""Held (shared) by that run and by each of its local workers, as long as they live."""
WATCHDOG_S = 0.5
"""How often a worker checks that its parent still lives (where no parent-death signal)."""
_held: list = []   # the lock file a worker holds for its lifetime


def _end_with_parent(parent: int) -> None:
    """
    End this process as soon as the process ``parent`` ends, even when it is killed.

    On Linux the kernel sends SIGKILL on the parent's death (``PR_SET_PDEATHSIG``);
    everywhere a thread checks the parent pid every :data:`WATCHDOG_S` seconds too.
    """
    if sys.platform.startswith('linux'):
        try:
            libc = ctypes.CDLL(ctypes.util.find_library('c') or 'libc.so.6', use_errno=True)
            libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)   # 1: PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass  # the watchdog below does it
    if os.getppid() != parent:
        os._exit(1)   # the parent died before the signal was asked for

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(WATCHDOG_S)
        os._exit(1)
    threading.Thread(target=watch, name='fleet-parent-watchdog', daemon=True).start()


def worker_start(out: Optional[Union[str, os.PathLike]], parent: Optional[int]) -> None:
    """
    Start a fleet worker process: end with ``parent`` (a pid), hold the output folder ``out``.

    The worker holds ``out``'s :data:`WORKERS_LOCK` shared for its lifetime, so
    that no later run writes into ``out`` while it lives (:class:`OutputLock`).
    """
    if parent is not None:
        _end_with_parent(parent)
    if out is not None and fcntl is not None:
        fd = os.open(Path(out) / WORKERS_LOCK, os.O_RDWR | os.O_CREAT, 0o644)
        fcntl.flock(fd, fcntl.LOCK_SH)
        _held.append(fd)


def _lock_holders(path: Path) -> list[int]:
    """Return the pids holding a lock on ``path`` (from /proc/locks; empty where unknown)."""
    try:
        inode = path.stat().st_ino
        text = Path('/proc/locks').read_text()
    except OSError:
        return []
    pids = []
    for line in text.splitlines():
        fields = line.split()
        if '->' in fields:
            fields.remove('->')   # a waiter
        if len(fields) > 5 and fields[5].rsplit(':', 1)[-1] == str(inode) and \
                fields[4].isdigit() and int(fields[4]) != os.getpid():
            pids.append(int(fields[4]))
    return sorted(set(pids))


class OutputLock:
    """
    One fleet run at a time in an output folder, and none while a worker of an earlier run lives.

    The run holds :data:`RUN_LOCK` exclusively (its pid written in it) and
    :data:`WORKERS_LOCK` shared, as does each of its local workers: a second run
    is refused while the first lives, and while any worker of a killed run is
    still writing. The locks go with their processes (``flock``), so the lock of a
    dead run is simply taken over. Stale temporary files of a killed run are then
    removed.
    """

    def __init__(self, out: Path) -> None:
        self.out = Path(out)
        self.fds: list[int] = []

    def __enter__(self) -> 'OutputLock':
        """Take the folder (a :class:`FleetError` when it is in use)."""
        if fcntl is None:
            return self
        try:
            run = os.open(self.out / RUN_LOCK, os.O_RDWR | os.O_CREAT, 0o644)
            self.fds.append(run)
            try:
                fcntl.flock(run, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                pid = os.pread(run, 32, 0).decode(errors='replace').strip() or '?'
                raise FleetError(f'output {self.out} is in use by another fleet run (pid {pid}); '
                                 'wait for it to end or give another --out') from None
            workers = os.open(self.out / WORKERS_LOCK, os.O_RDWR | os.O_CREAT, 0o644)
            self.fds.append(workers)
            try:
                fcntl.flock(workers, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                pids = ', '.join(map(str, _lock_holders(self.out / WORKERS_LOCK))) or 'unknown'
                raise FleetError(f'output {self.out} is still written by a worker of an earlier '
                                 f'fleet run whose parent died (pid {pids}); wait for it to '
                                 'end or stop it, then run again') from None
            fcntl.flock(workers, fcntl.LOCK_SH)
            os.ftruncate(run, 0)
            os.pwrite(run, f'{os.getpid()}\n'.encode(), 0)
        except BaseException:
            self.release()
            raise
        _remove_leftovers(self.out)
        return self

    def release(self) -> None:
        """Let the folder go."""
        for fd in self.fds:
            os.close(fd)
        self.fds = []

    def __exit__(self, *exc: Any) -> None:
        """Let the folder go."""
        self.release()


def _remove_leftovers(out: Path) -> None:
    """Remove what a killed run left half-written in ``out`` (no live process writes there)."""
    stale = [p for p in out.glob('.*.tmp') if p.is_file()]
    for robot in (out / 'bags').glob('*'):
        stale += [p for p in robot.glob('.*') if '.partial-' in p.name or '.old-' in p.name]
        stale += list(robot.glob('*/fleet.tmp'))
    for path in stale:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)


def _progress(total: int, progress: Optional[bool]) -> Any:
    show = sys.stderr.isatty() if progress is None else bool(progress)
    if not show:
        return None
    from tqdm import tqdm
    return tqdm(total=total, unit='bag', file=sys.stderr, desc='fleet', dynamic_ncols=True)


Lost = Callable[[Any, str], Any]
"""Makes the result of a call whose worker process died: ``lost(item, reason)``."""

LOST_REASON = 'its worker process died while running it (killed, out of memory or crashed)'


class _InProcess:
    """Runs every call in this process, one after another (``--workers 1``)."""

    def each(self, function: Callable, items: Iterable, *args: Any,
             lost: Lost) -> Iterator[Any]:
        """Yield ``function(item, *args)`` for each item (``lost``: for a dead worker)."""
        for item in items:
            yield function(item, *args)

    def close(self) -> None:
        """Nothing to release."""


class _Pool(_InProcess):
    """
    Local worker processes, one call in flight on each, results as they come.

    Each worker is a process pool of its own: a worker that dies (killed, out of
    memory, a crash in a C library) breaks only its own pool, in the middle of
    exactly one call, which is lost (``lost``); a fresh worker takes its place.
    """

    def __init__(self, workers: int, out: Optional[Path] = None) -> None:
        self.out = None if out is None else str(out)
        self.pools = [self._new_pool() for _ in range(workers)]

    def _new_pool(self) -> ProcessPoolExecutor:
        """Return a pool of one worker that ends with this process and holds the output."""
        context = multiprocessing.get_context('spawn')  # no state shared with the parent
        return ProcessPoolExecutor(max_workers=1, mp_context=context, initializer=worker_start,
                                   initargs=(self.out, os.getpid()))

    def each(self, function: Callable, items: Iterable, *args: Any,
             lost: Lost) -> Iterator[Any]:
        """Yield ``function(item, *args)`` for each item, in the order they finish."""
        queue = list(items)[::-1]
        idle = list(range(len(self.pools)))
        running: dict = {}
        while queue or running:
            while queue and idle:
                k = idle.pop()
                item = queue.pop()
                running[self.pools[k].submit(function, item, *args)] = (k, item)
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                k, item = running.pop(future)
                idle.append(k)
                if not isinstance(future.exception(), BrokenProcessPool):
                    yield future.result()
                    continue
                self.pools[k].shutdown(wait=True)
                self.pools[k] = self._new_pool()
                yield lost(item, LOST_REASON)

    def close(self) -> None:
        """Stop the workers (calls not started yet are dropped)."""
        for pool in self.pools:
            pool.shutdown(cancel_futures=True)


class _Ray(_InProcess):
    """Ray tasks: ``address`` of a cluster, or ``auto`` for a local Ray with ``workers`` CPUs."""

    def __init__(self, address: str, workers: int) -> None:
        try:
            import ray
        except ImportError:
            raise FleetError('--ray needs Ray, an optional extra: pip install -r '
                             'requirements-ray.txt (or pip install .[ray])') from None
        self.ray = ray
        self.started = not ray.is_initialized()
        if self.started:
            if address == 'auto':
                ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
            else:
                ray.init(address=address, log_to_driver=False)

    def each(self, function: Callable, items: Iterable, *args: Any,
             lost: Lost) -> Iterator[Any]:
        """
        Yield ``function(item, *args)`` for each item, in the order they finish.

        A task Ray gives up on (its worker died more often than Ray retries a task)
        yields ``lost``.
        """
        task = self.ray.remote(function)
        pending = {task.remote(item, *args): item for item in items}
        while pending:
            done, _ = self.ray.wait(list(pending), num_returns=1)
            item = pending.pop(done[0])
            try:
                result = self.ray.get(done[0])
            except self.ray.exceptions.RayError as exc:
                result = lost(item, f'{LOST_REASON} ({type(exc).__name__})')
            yield result

    def close(self) -> None:
        """Shut down a Ray this run started."""
        if self.started:
            self.ray.shutdown()


def check_settings(nodes: Optional[Iterable[str]], params_file: Any,
                   overrides: Iterable[str]) -> None:
    """
    Refuse node names, a parameter file and ``--set`` items that would fail every bag.

    The same checks a replay makes before it reads a bag, made once: a typo
    gives one line and exit 2 instead of a fleet whose every bag failed.
    """
    from robot_calib import methods
    from robot_calib.replay.config import check_override_nodes, load_params_file, params_for, \
        parse_overrides, resolve_node
    chosen = [resolve_node(n) for n in nodes] if nodes else \
        [resolve_node(n) for n in methods.available()]
    file_params = load_params_file(params_file)
    by_node = parse_overrides(list(overrides))
    check_override_nodes(by_node, {name for name, _ in chosen})
    for name, cls in chosen:
        params_for(name, cls, file_params, by_node.get(name, {}))


def run_fleet(source: Union[str, os.PathLike], out: Union[str, os.PathLike],
              nodes: Optional[Iterable[str]] = None, workers: Optional[int] = None,
              force: bool = False, params_file: Optional[Union[str, os.PathLike]] = None,
              overrides: Iterable[str] = (), flag_sigma: float = 4.0,
              progress: Optional[bool] = None, ray: Optional[str] = None,
              bag_plots: bool = False) -> dict[str, Any]:
    """
    Run the fleet job; return ``{'bags', 'failed', 'flags', 'rows', 'seconds', 'notes'}``.

    ``notes``: what the run did that a user should know (bags reached twice and
    counted once, bags done before that changed and were replayed again); also
    in ``report.md``. A full disk raises :class:`DiskFull` (exit status 2), with
    nothing half-written left; an output folder another live run (or a worker
    of a killed one) writes into is refused.

    :param source: a folder (one subfolder per robot) or a manifest (.csv/.yaml)
    :param out: the result folder (created; bags already done there are reused)
    :param nodes: the nodes to run (default: every node whose inputs are in a bag)
    :param workers: worker processes (default: the CPU count)
    :param force: replay every bag again, even one done with the same code and parameters
    :param params_file: a ROS 2 parameter YAML for every robot (a manifest may name one per bag)
    :param overrides: ``NODE.PARAM=VALUE`` items
    :param flag_sigma: how far (in sigma) an estimate may move before it is flagged
    :param progress: show a progress bar across bags (default: when stderr is a terminal)
    :param ray: run on Ray instead of the process pool: a cluster address, or ``auto`` for a
        local Ray with ``workers`` CPUs
    :param bag_plots: draw each bag's replay plots too (about 0.5 s a bag; off by default,
        the fleet report has its own)
    """
    t0 = time.perf_counter()
    if not flag_sigma > 0:
        raise FleetError(f'bad --flag-sigma {flag_sigma}: expected a positive number')
    workers = (os.cpu_count() or 1) if workers is None else int(workers)
    if workers < 1:
        raise FleetError(f'bad --workers {workers}: expected 1 or more')
    check_settings(nodes, params_file, overrides)
    out = Path(out)
    notes: list[str] = []
    jobs = discover(Path(source), out, notes)
    ours = {RUN_LOCK, WORKERS_LOCK}   # all a run killed at once leaves
    if out.exists() and (not out.is_dir() or (
            any(p.name not in ours for p in out.iterdir()) and not (
                (out / 'results.csv').is_file() or (out / 'bags').is_dir()))):
        raise FleetError(f'output {out} exists and is not an empty folder or a previous fleet '
                         'output; give a new or empty folder')
    try:
        out.mkdir(parents=True, exist_ok=True)
        with OutputLock(out):
            return _run(jobs, out, notes, t0, nodes, workers, force, params_file, overrides,
                        flag_sigma, progress, ray, bag_plots)
    except OSError as exc:
        if disk_full(exc):
            raise disk_full_error(out) from None
        raise


def _run(jobs: list[Job], out: Path, notes: list[str], t0: float,
         nodes: Optional[Iterable[str]], workers: int, force: bool,
         params_file: Optional[Union[str, os.PathLike]], overrides: Iterable[str],
         flag_sigma: float, progress: Optional[bool], ray: Optional[str],
         bag_plots: bool) -> dict[str, Any]:
    """Run the jobs into ``out`` (held by this run); see :func:`run_fleet`."""
    settings = Settings(out.resolve(), tuple(nodes) if nodes else None,
                        Path(params_file).resolve() if params_file else None,
                        tuple(overrides), force, bag_plots)
    workers = min(workers, len(jobs))
    executor = _Ray(ray, workers) if ray else _Pool(workers, out.resolve()) if workers > 1 \
        else _InProcess()
    try:
        bar = _progress(len(jobs), progress)
        done: list[dict] = []
        redone: list[str] = []
        try:
            for part, note in executor.each(
                    run_noted, jobs, settings,
                    lost=lambda job, why: (failed_rows(job, why, 0.0, None), '')):
                done += part
                if note:
                    redone.append(note)
                if bar is not None:
                    bar.update(1)
        finally:
            if bar is not None:
                bar.close()
        notes += sorted(redone)
        rows = results.sort_rows(done)
        found = results.flags(rows, flag_sigma)
        results.write_table(rows, out)
        results.write_flags(found, out)
        seconds = time.perf_counter() - t0
        # the figures (one a robot) are drawn by the same workers
        report.write_report(rows, found, out, seconds,
                            lambda calls: executor.each(report.draw, calls, lost=lambda c, w: ''),
                            notes=notes)
    finally:
        executor.close()
    failed = len({r['bag'] for r in rows if r['status'] == 'failed'})
    return {'bags': len(jobs), 'failed': failed, 'flags': len(found), 'rows': rows,
            'seconds': seconds, 'notes': notes}
