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

from concurrent.futures import as_completed, ProcessPoolExecutor
import multiprocessing
import os
from pathlib import Path
import sys
import time
from typing import Any, Iterable, Optional, Union

from robot_calib.fleet import report, results
from robot_calib.fleet.runner import run_job, Settings
from robot_calib.fleet.source import discover, FleetError, Job

__all__ = ['FleetError', 'Job', 'run_fleet']


def _progress(total: int, progress: Optional[bool]) -> Any:
    show = sys.stderr.isatty() if progress is None else bool(progress)
    if not show:
        return None
    from tqdm import tqdm
    return tqdm(total=total, unit='bag', file=sys.stderr, desc='fleet', dynamic_ncols=True)


def _run_all(jobs: list[Job], settings: Settings, workers: int, bar: Any) -> list[dict]:
    rows: list[dict] = []
    if workers <= 1:
        for job in jobs:
            rows += run_job(job, settings)
            if bar is not None:
                bar.update(1)
        return rows
    context = multiprocessing.get_context('spawn')  # no state shared with the parent
    with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
        futures = [pool.submit(run_job, job, settings) for job in jobs]
        for future in as_completed(futures):
            rows += future.result()
            if bar is not None:
                bar.update(1)
    return rows


def _run_ray(jobs: list[Job], settings: Settings, address: str, workers: int,
             bar: Any) -> list[dict]:
    """Run the jobs as Ray tasks: ``address`` of a cluster, or ``auto`` for a local Ray."""
    try:
        import ray
    except ImportError:
        raise FleetError('--ray needs Ray, an optional extra: pip install -r '
                         'requirements-ray.txt (or pip install .[ray])') from None
    started = not ray.is_initialized()
    if started:
        if address == 'auto':
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, log_to_driver=False)
    try:
        task = ray.remote(run_job)
        pending = [task.remote(job, settings) for job in jobs]
        rows: list[dict] = []
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            rows += ray.get(done[0])
            if bar is not None:
                bar.update(1)
        return rows
    finally:
        if started:
            ray.shutdown()


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
    jobs = discover(Path(source))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    settings = Settings(out.resolve(), tuple(nodes) if nodes else None,
                        Path(params_file).resolve() if params_file else None,
                        tuple(overrides), force, bag_plots)
    bar = _progress(len(jobs), progress)
    try:
        if ray:
            done = _run_ray(jobs, settings, ray, workers, bar)
        else:
            done = _run_all(jobs, settings, min(workers, len(jobs)), bar)
        rows = results.sort_rows(done)
    finally:
        if bar is not None:
            bar.close()
    found = results.flags(rows, flag_sigma)
    results.write_table(rows, out)
    results.write_flags(found, out)
    seconds = time.perf_counter() - t0
    report.write_report(rows, found, out, seconds)
    failed = len({r['bag'] for r in rows if r['status'] == 'failed'})
    return {'bags': len(jobs), 'failed': failed, 'flags': len(found), 'rows': rows,
            'seconds': seconds}
