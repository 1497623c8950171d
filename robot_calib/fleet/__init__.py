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
"""

from __future__ import annotations

from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
import multiprocessing
import os
from pathlib import Path
import sys
import time
from typing import Any, Callable, Iterable, Iterator, Optional, Union

from robot_calib.fleet import report, results
from robot_calib.fleet.runner import failed_rows, run_job, Settings
from robot_calib.fleet.source import discover, FleetError, Job

__all__ = ['FleetError', 'Job', 'run_fleet']


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

    def __init__(self, workers: int) -> None:
        self.pools = [self._new_pool() for _ in range(workers)]

    @staticmethod
    def _new_pool() -> ProcessPoolExecutor:
        context = multiprocessing.get_context('spawn')  # no state shared with the parent
        return ProcessPoolExecutor(max_workers=1, mp_context=context)

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
    from robot_calib import pipelines
    from robot_calib.replay.config import check_override_nodes, load_params_file, params_for, \
        parse_overrides, resolve_node
    chosen = [resolve_node(n) for n in nodes] if nodes else \
        [resolve_node(n) for n in pipelines.available()]
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
    Run the fleet job; return ``{'bags', 'failed', 'flags', 'rows', 'seconds'}``.

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
    jobs = discover(Path(source), out)
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not (
            (out / 'results.csv').is_file() or (out / 'bags').is_dir()))):
        raise FleetError(f'output {out} exists and is not an empty folder or a previous fleet '
                         'output; give a new or empty folder')
    out.mkdir(parents=True, exist_ok=True)
    settings = Settings(out.resolve(), tuple(nodes) if nodes else None,
                        Path(params_file).resolve() if params_file else None,
                        tuple(overrides), force, bag_plots)
    workers = min(workers, len(jobs))
    executor = _Ray(ray, workers) if ray else _Pool(workers) if workers > 1 else _InProcess()
    try:
        bar = _progress(len(jobs), progress)
        done: list[dict] = []
        try:
            for part in executor.each(run_job, jobs, settings,
                                      lost=lambda job, why: failed_rows(job, why, 0.0, None)):
                done += part
                if bar is not None:
                    bar.update(1)
        finally:
            if bar is not None:
                bar.close()
        rows = results.sort_rows(done)
        found = results.flags(rows, flag_sigma)
        results.write_table(rows, out)
        results.write_flags(found, out)
        seconds = time.perf_counter() - t0
        # the figures (one a robot) are drawn by the same workers
        report.write_report(rows, found, out, seconds,
                            lambda calls: executor.each(report.draw, calls, lost=lambda c, w: ''))
    finally:
        executor.close()
    failed = len({r['bag'] for r in rows if r['status'] == 'failed'})
    return {'bags': len(jobs), 'failed': failed, 'flags': len(found), 'rows': rows,
            'seconds': seconds}
