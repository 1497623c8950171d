# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The ``robot-calib`` command line: ``simulate``, ``replay``, ``mismatch`` and ``ideal``.

Bad input of any kind (a missing, truncated or corrupt bag, an unknown node,
topic or type, an unwritable output folder, a bad ``--set``/``--remap``/
``--params``) ends with ONE line on stderr naming the problem and what was
expected, and exit status 2; nothing half-written is left behind.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import logging
import os
from pathlib import Path
import signal
import sys
import threading
from typing import Any, Iterator, Optional, Sequence

_EXIT_BAD_INPUT = 2


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line on stderr and exit status 2."""

    def error(self, message: str) -> None:  # noqa: D102 - argparse hook
        self.exit(_EXIT_BAD_INPUT, f'{self.prog}: error: {" ".join(message.split())} '
                                   f'(see {self.prog} --help)\n')


def _add_simulate(sub: Any) -> None:
    """Add the ``simulate`` verb."""
    p = sub.add_parser('simulate', help='write a simulated ROS 2 bag with ground truth',
                       description='Simulate a scenario and write a ROS 2 bag plus '
                                   '<out>.truth.json.')
    p.add_argument('scenario', help='scenario name (e.g. drive, vacuum, revisit, tip_over), '
                                    'or fleet: a folder of robots with drifting parameters '
                                    '(--set fleet.robots=N, ...: the keys of '
                                    'robot_calib/sim/fleet.py; README, "Offline"), or follow '
                                    "REAL_BAG: the robot driven by a real recording's velocity "
                                    'commands, on its clock, under its topic names')
    p.add_argument('source', nargs='?', default=None, metavar='REAL_BAG',
                   help='follow: the real recording whose commands drive the robot')
    p.add_argument('--params', default=None, metavar='FILE',
                   help='follow: simulator parameter YAML (sim_params.yaml of mismatch, or '
                        'config/sim.yaml keys); --set wins over it')
    p.add_argument('--cmd-topic', default=None, metavar='TOPIC',
                   help='follow: the velocity-command topic (default: cmd_vel by name, else '
                        'the only Twist/TwistStamped topic)')
    p.add_argument('--out', required=True, help='output bag folder')
    p.add_argument('--seed', type=int, default=0, help='random seed (default 0)')
    p.add_argument('--duration', type=float, default=None, help='duration in s')
    p.add_argument('--set', dest='overrides', action='append', default=[],
                   metavar='KEY=VALUE', help='override a simulator parameter (repeatable)')
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                   help='bag storage (default mcap)')


def _add_replay(sub: Any) -> None:
    """Add the ``replay`` verb."""
    p = sub.add_parser('replay', help='run the nodes over bags offline (or --live)',
                       description="Replay bags through the nodes' core code as fast as "
                                   'possible; writes DIR/output.mcap, DIR/summary.json, '
                                   'DIR/report.md.')
    p.add_argument('bags', nargs='+', metavar='BAG',
                   help='ROS 2 bag folder(s) (mcap or sqlite3), .mcap file(s) or ROS 1 .bag '
                        'file(s)')
    p.add_argument('--out', metavar='DIR', help='output folder (required unless --live)')
    p.add_argument('--nodes', default=None,
                   help='comma-separated nodes (executable names or package.module:Class); '
                        'default: every node whose inputs are in the bag')
    p.add_argument('--remap', action='append', default=[], metavar='FROM:=TO',
                   help='remap a node topic (imu:=/imu/data) or a bag topic (repeatable)')
    p.add_argument('--params', default=None, metavar='FILE',
                   help='ROS 2 parameter YAML (config/robot_calib.yaml format)')
    p.add_argument('--set', dest='overrides', action='append', default=[],
                   metavar='NODE.PARAM=VALUE', help='override one node parameter (repeatable)')
    p.add_argument('--live', action='store_true',
                   help='publish the bag through rclpy at the recorded rate with /clock')
    p.add_argument('--rate', type=float, default=None,
                   help='--live playback rate factor (default 1.0)')
    p.add_argument('--loop', action='store_true',
                   help='--live: play the recording again and again until interrupted')
    p.add_argument('--topics', nargs='+', default=None, metavar='TOPIC',
                   help='--live: publish only these bag topics (after --remap)')
    p.add_argument('--start-offset', type=float, default=0.0, metavar='S',
                   help='skip the first S seconds of the recording')
    p.add_argument('--duration', type=float, default=None, metavar='S',
                   help='replay (or play) at most S seconds')
    p.add_argument('--no-plots', action='store_true',
                   help='write the report without its plots (about 0.5 s less a replay)')
    p.add_argument('--no-progress', action='store_true', help='never show a progress bar')


def _add_mismatch(sub: Any) -> None:
    """Add the ``mismatch`` verb."""
    p = sub.add_parser('mismatch', help='compare a simulated and a real recording',
                       description='Explain what a simulation left out: writes '
                                   'DIR/findings.json and a report.')
    p.add_argument('--sim', required=True, metavar='SIM_BAG', help='simulated bag')
    p.add_argument('--real', required=True, metavar='REAL_BAG', help='real bag')
    p.add_argument('--out', required=True, metavar='DIR', help='output folder')
    p.add_argument('--remap', action='append', default=[], metavar='SIM_TOPIC:=REAL_TOPIC',
                   help='compare these two topics (repeatable); topics of different types '
                        'are compared on what they share (an IMU yaw rate with an odometry '
                        "yaw rate, a velocity command's speed with an odometry speed)")
    p.add_argument('--corrected', default=None, metavar='SIM_BAG',
                   help='a simulation with the findings applied (simulate follow REAL_BAG '
                        '--params DIR/sim_params.yaml of an earlier run): the report shows '
                        'its trajectory and pose drift beside the simulated and real ones')


def _add_ideal(sub: Any) -> None:
    """Add the ``ideal`` verb."""
    p = sub.add_parser('ideal', help='derive ideal sensors from a ground-truth recording',
                       description='Write the recording a perfect robot would have made '
                                   '(/imu, /odom, and /joint_states with --set drive_type=...) '
                                   'from a ground-truth motion (motion capture poses or '
                                   'ground-truth odometry), to compare with the real sensors '
                                   'by robot-calib mismatch.')
    p.add_argument('truth', metavar='TRUTH_BAG', help='bag with the ground-truth poses')
    p.add_argument('--out', required=True, metavar='SIM_BAG', help='output bag folder')
    p.add_argument('--truth-topic', default=None, metavar='TOPIC',
                   help='the ground-truth topic (default: the only pose topic, or the one '
                        'named truth / mocap / vrpn / vicon / optitrack)')
    p.add_argument('--set', dest='overrides', action='append', default=[], metavar='KEY=VALUE',
                   help='imu_xyz, imu_rpy, gravity, rel_noise, max_window, drive_type, '
                        'wheel_radius, track_width, wheel_base; for /scan: map_resolution, '
                        'map_min_hits, lidar_x, lidar_y, lidar_yaw (without /tf_static), '
                        'scan_rate, scan_beams, scan_fov, scan_range_min, scan_range_max, '
                        'scan_frame (without real scans) (repeatable)')
    p.add_argument('--map', default=None, metavar='MAP.yaml',
                   help='also write /scan: beams ray-cast at the true poses in this '
                        'occupancy grid (map_server YAML with a PGM or PNG image, in the frame '
                        "of the truth's poses), with the real scanner's angles, range limits "
                        'and stamps')
    p.add_argument('--map-from-scans', action='store_true',
                   help='also write /scan, cast in a map built from the real scans at the true '
                        'poses (it absorbs their range bias and part of their scale)')
    p.add_argument('--scan-topic', default=None, metavar='TOPIC',
                   help='the real LaserScan topic (default: the only one, or /scan)')


def _add_fleet(sub: Any) -> None:
    """Add the ``fleet`` verb."""
    p = sub.add_parser('fleet', help="run every robot's bags through the nodes, in parallel",
                       description='Replay every bag of a fleet (a folder with one subfolder '
                                   'per robot, or a manifest) on worker processes; writes '
                                   'DIR/results.csv and .parquet, DIR/flags.csv, DIR/report.md '
                                   'and each replay under DIR/bags/<robot>/<bag>/.')
    p.add_argument('source', metavar='SOURCE', help='fleet folder or manifest (.csv/.yaml)')
    p.add_argument('--out', required=True, metavar='DIR', help='result folder')
    p.add_argument('--nodes', default=None, help='comma-separated nodes (default: every node '
                                                 'whose inputs are in the bag)')
    p.add_argument('--workers', type=int, default=None, metavar='N',
                   help='worker processes (default: the CPU count)')
    p.add_argument('--ray', default=None, metavar='ADDRESS',
                   help='run on a Ray cluster at ADDRESS, or "auto" for a local Ray (needs '
                        'the optional extra: pip install -r requirements-ray.txt)')
    p.add_argument('--force', action='store_true',
                   help='replay bags already done with the same code and parameters again')
    p.add_argument('--params', default=None, metavar='FILE', help='ROS 2 parameter YAML')
    p.add_argument('--set', dest='overrides', action='append', default=[],
                   metavar='NODE.PARAM=VALUE', help='override one node parameter (repeatable)')
    p.add_argument('--flag-sigma', type=float, default=4.0, metavar='K',
                   help='flag an estimate that moves more than K sigma from its history')
    p.add_argument('--bag-plots', action='store_true',
                   help="also draw each bag's replay plots (about 0.5 s a bag; the fleet "
                        'report has its own)')
    p.add_argument('--no-progress', action='store_true', help='never show a progress bar')


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser of ``robot-calib``."""
    parser = _Parser(prog='robot-calib',
                     description='Calibration and estimation for low-cost wheeled robots.')
    sub = parser.add_subparsers(dest='verb', metavar='VERB', parser_class=_Parser)
    sub.required = True
    for add in (_add_simulate, _add_replay, _add_mismatch, _add_ideal, _add_fleet):
        add(sub)
    return parser


def _parse_sets(items: Sequence[str]) -> dict[str, str]:
    out = {}
    for item in items:
        key, sep, value = item.partition('=')
        if not sep or not key.strip():
            raise ValueError(f'bad --set {item!r}: expected KEY=VALUE')
        out[key.strip()] = value.strip()
    return out


def _make_parent(path: str) -> None:
    """Create the folder a bag will be written into (as replay does for its output)."""
    try:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    except OSError:
        pass  # the bag writer says what is wrong with it, in one line


def _simulate(args: argparse.Namespace) -> int:
    from robot_calib import sim
    _make_parent(args.out)
    if args.scenario == 'follow':
        return _follow(args)
    if args.source is not None or args.params is not None or args.cmd_topic is not None:
        raise ValueError(f'REAL_BAG, --params and --cmd-topic belong to simulate follow, not '
                         f'to scenario {args.scenario}')
    if args.scenario == 'fleet':
        from robot_calib.sim.fleet import simulate_fleet
        rows = simulate_fleet(args.out, seed=args.seed, duration=args.duration,
                              overrides=args.overrides or None, storage=args.storage)
        robots = len({r['robot'] for r in rows})
        drifts = sorted({f'{r["robot"]} {r["drift"]}' for r in rows if r['drift'] != 'unchanged'})
        print(f'wrote {len(rows)} bags of {robots} robots into {args.out} '
              f'({len(drifts)} drifting; truth in {args.out}/fleet_truth.csv)')
        return 0
    truth = sim.simulate(args.scenario, args.out, seed=args.seed, duration=args.duration,
                         overrides=_parse_sets(args.overrides) or None, storage=args.storage)
    print(f'wrote {args.out} and {args.out}.truth.json (scenario {args.scenario}, '
          f'seed {args.seed}, {len(truth)} truth keys)')
    return 0


def _follow(args: argparse.Namespace) -> int:
    from robot_calib.sim.follow import follow
    if args.source is None:
        raise ValueError('simulate follow needs the real recording: simulate follow REAL_BAG '
                         '--out SIM_BAG')
    if args.duration is not None:
        raise ValueError('--duration does not apply to follow: the run lasts as long as the '
                         'recording')
    truth = follow(args.source, args.out, seed=args.seed,
                   overrides=_parse_sets(args.overrides) or None, params_file=args.params,
                   cmd_topic=args.cmd_topic, storage=args.storage)
    written = ', '.join(f'{t} ({k})' for t, k in truth['topic_map'].items())
    print(f'followed {truth["commands"]} commands of {truth["command_topic"]} '
          f'({truth["command_type"].rsplit("/", 1)[-1]}) over {truth["duration"]:.1f} s from '
          f'{truth["start_time"]:.3f}; wrote {args.out} ({written}) and '
          f'{args.out}.truth.json')
    return 0


def _warn_corrupt(chunks: list) -> None:
    """Say on stderr how many corrupt mcap chunks were skipped (their data was not used)."""
    if chunks:
        lost = sum(n for c in chunks for n in c['messages'].values())
        print(f'robot-calib replay: warning: skipped {len(chunks)} corrupt mcap chunk(s), '
              f'{lost} message(s) not used (first: {chunks[0]["reason"]} at byte '
              f'{chunks[0]["offset"]} of {chunks[0]["file"]})', file=sys.stderr)


def _warn_duplicate_joints(summary: dict) -> None:
    """Say on stderr how many joint states were rejected for naming a joint twice."""
    counts: dict[str, int] = {}
    for node in summary['nodes'].values():
        for key, c in (node.get('inputs') or {}).items():
            n = c.get('rejected_duplicate_joint', 0) if isinstance(c, dict) else 0
            if n:
                counts[key] = max(counts.get(key, 0), n)
    for key, n in counts.items():
        print(f'robot-calib replay: warning: {n} {key} message(s) name a joint twice and were '
              "rejected (which value is the joint's cannot be told; inputs "
              'rejected_duplicate_joint in summary.json)', file=sys.stderr)


def _replay(args: argparse.Namespace) -> int:
    if args.live:
        from robot_calib import live
        offline = [flag for flag, given in (('--out', args.out), ('--nodes', args.nodes),
                                            ('--set', args.overrides), ('--params', args.params))
                   if given]
        if offline:
            raise ValueError(f'{", ".join(offline)} belong to offline replay (--live only '
                             'publishes the bag; run the nodes with ros2 run); drop them or '
                             '--live')
        rate = 1.0 if args.rate is None else args.rate
        if rate <= 0 or rate != rate:
            raise ValueError(f'bad --rate {rate}: expected a positive factor')
        stats = live.play(args.bags, rate=rate, remaps=args.remap, topics=args.topics,
                          start_offset=args.start_offset, duration=args.duration,
                          loops=0 if args.loop else 1)
        print(f'published {stats["messages"]} messages on {len(stats["topics"])} topics '
              f'in {stats["wall_seconds"]:.1f} s')
        for topic, why in stats['skipped'].items():
            print(f'not published {topic}: {why}')
        _warn_corrupt(stats['corrupt_chunks'])
        return 0
    if args.loop or args.topics is not None or args.rate is not None:
        raise ValueError('--loop, --topics and --rate belong to --live (offline replay reads '
                         'the topics its nodes need, as fast as it can); add --live or drop '
                         'them')
    if not args.out:
        raise ValueError('replay needs --out DIR (or --live)')
    from robot_calib.replay import replay
    summary = replay(args.bags, args.out, nodes=args.nodes, remaps=args.remap,
                     params_file=args.params, overrides=args.overrides,
                     progress=False if args.no_progress else None,
                     start_offset=args.start_offset, duration=args.duration,
                     plots=not args.no_plots)
    nodes = ', '.join(summary['nodes']) or 'none'
    print(f'replayed {summary["timing"]["messages"]} messages through {nodes} in '
          f'{summary["timing"]["wall_seconds"]:.2f} s; wrote {args.out}/output.mcap, '
          f'summary.json, report.md')
    for name, why in summary['skipped'].items():
        print(f'skipped {name}: {why}')
    for note in dict.fromkeys(n for node in summary['nodes'].values()
                              for n in node.get('notes', ()) if n.startswith('input ')):
        print(note)
    if summary['nodes'] and not summary['timing']['messages'] and summary.get('window'):
        start, length = summary['window']
        print(f'robot-calib replay: warning: no message in the time window from {start:g} s'
              + (f' for {length:g} s' if length is not None else '') +
              f' of the {summary["duration"]:.1f} s recording; the outputs are empty',
              file=sys.stderr)
    _warn_corrupt(summary['corrupt_chunks'])
    _warn_duplicate_joints(summary)
    for topic, n in summary['restamped'].items():
        print(f'robot-calib replay: warning: {n} message(s) on {topic} have no header stamp '
              '(0): their receive time in the bag was used instead', file=sys.stderr)
    for name, node in summary['nodes'].items():
        errors = node.get('errors') if isinstance(node.get('errors'), dict) else \
            node.get('replay_errors', {})
        if errors:
            first = (node.get('first_errors') or node.get('replay_first_errors') or [''])[0]
            print(f'robot-calib replay: warning: {name} raised errors {errors}'
                  + (f' (first: {first})' if first else ''), file=sys.stderr)
    return 0


def _mismatch(args: argparse.Namespace) -> int:
    from robot_calib import mismatch
    from robot_calib.replay import parse_remaps
    findings = mismatch.analyse(args.sim, args.real, args.out, remaps=parse_remaps(args.remap),
                                corrected=args.corrected)
    n = len(findings.get('findings', [])) if isinstance(findings, dict) else 0
    verdict = findings.get('verdict', '?') if isinstance(findings, dict) else '?'
    print(f'{verdict}: {n} finding(s); wrote {args.out}/findings.json, report.md, '
          'sim_params.yaml, suggestions.yaml')
    traj = findings.get('trajectory') if isinstance(findings, dict) else None
    if traj:
        for k, label in (('sim_drift', 'simulated'), ('corrected_drift', 'corrected')):
            if traj.get(k):
                print(f'{label} vs real on {traj["topic"]}: end drift {traj[k]["end_m"]:.3f} m, '
                      f'RMS {traj[k]["rms_m"]:.3f} m over {traj["span_s"]:.0f} s')
    return 0


def _ideal(args: argparse.Namespace) -> int:
    from robot_calib.core.params import from_flat
    from robot_calib.mismatch import derive
    from robot_calib.mismatch.channels import ChannelError
    sets = _parse_sets(args.overrides)
    for key in ('imu_xyz', 'imu_rpy'):
        if key in sets:
            sets[key] = [v for v in sets[key].strip('[]').split(',') if v.strip()]
    params = from_flat(derive.IdealParams, sets)
    _make_parent(args.out)
    scan = derive.ScanRequest(args.map, args.map_from_scans, args.scan_topic)
    try:
        info = derive.derive(args.truth, args.out, args.truth_topic, params, scan)
    except ChannelError as exc:
        raise ValueError(str(exc)) from None
    widths = ', '.join(f'{t} {f}: {k[0]} +-{k[1] * 1000:.0f} ms' for t, ks in
                       info['kernels'].items() for f, k in list(ks.items())[:1])
    print(f'wrote {args.out}: {info["messages"]} messages from {info["poses"]} poses of '
          f'{info["truth_topic"]} ({info["span_s"]:.1f} s); smoothing {widths}')
    cleaned = [f'{info[k]} {what}' for k, what in (
        ('poses_dropped', 'poses dropped (zero or non-finite quaternion or position)'),
        ('quaternions_normalised', 'quaternions normalised (not unit length)'),
        ('gaps', 'gaps (in the truth or left by dropped poses), not differentiated across'))
        if info.get(k)]
    if cleaned:
        print('truth: ' + '; '.join(cleaned))
    sc = info.get('scan')
    if sc:
        print(f'{sc["topic"]}: {sc["scans"]} ideal scans of {sc["beams"]} beams, map '
              f'{sc["map"]} ({sc["map_cells"][1]} x {sc["map_cells"][0]} cells), laser '
              f'mounting from {sc["mount"]}')
        for note in sc['notes']:
            print(f'note: {note}')
    return 0


def _bad_input_types() -> tuple:
    """Return the exception types that mean bad input (exit status 2)."""
    from robot_calib.core.params import ParamError
    from robot_calib.io.bags import BagError
    types = [BagError, ParamError, ValueError, KeyError, FileNotFoundError,
             NotADirectoryError, PermissionError, IsADirectoryError, FileExistsError]
    for module, name in (('robot_calib.sim', 'SimError'),
                         ('robot_calib.mismatch', 'MismatchError')):
        try:
            types.append(getattr(importlib.import_module(module), name))
        except Exception:  # noqa: B902 - a module still being written must not break the CLI
            pass
    return tuple(types)


class Terminated(KeyboardInterrupt):
    """SIGTERM: unwinds like Ctrl-C, so that every half-written output is removed."""


@contextlib.contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """Raise :class:`Terminated` on SIGTERM while inside (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def _raise(signum: int, frame: Any) -> None:
        raise Terminated()
    previous = signal.signal(signal.SIGTERM, _raise)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


NOTES_SHOWN = 20
"""Fleet notes printed at most (bags replayed again because they changed...); all in report.md."""


def _fleet(args: argparse.Namespace) -> int:
    from robot_calib.fleet import run_fleet
    nodes = [n.strip() for n in args.nodes.split(',') if n.strip()] if args.nodes else None
    res = run_fleet(args.source, args.out, nodes=nodes, workers=args.workers, force=args.force,
                    params_file=args.params, overrides=args.overrides,
                    flag_sigma=args.flag_sigma, progress=False if args.no_progress else None,
                    ray=args.ray, bag_plots=args.bag_plots)
    print(f'{res["bags"]} bags in {res["seconds"]:.1f} s: {res["failed"]} failed, '
          f'{res["flags"]} flags; wrote {args.out}/results.csv, flags.csv, report.md')
    notes = res.get('notes', [])
    for note in notes[:NOTES_SHOWN]:
        print(note)
    if len(notes) > NOTES_SHOWN:
        print(f'... and {len(notes) - NOTES_SHOWN} more notes in {args.out}/report.md')
    if res['bags'] and res['failed'] == res['bags']:
        print(f'robot-calib fleet: error: every bag failed; the reasons are in '
              f'{args.out}/results.csv', file=sys.stderr)
        return 1
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Run ``robot-calib`` with ``argv`` (default: sys.argv); return the exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0) if not isinstance(exc.code, str) else _EXIT_BAD_INPUT
    verbs = {'simulate': _simulate, 'replay': _replay, 'mismatch': _mismatch, 'ideal': _ideal,
             'fleet': _fleet}
    try:
        with _sigterm_as_interrupt():
            return verbs[args.verb](args)
    except Terminated:
        print('robot-calib: terminated', file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        print('robot-calib: interrupted', file=sys.stderr)
        return 130
    except OSError as exc:
        if exc.errno not in _DISK_FULL:
            return _failure(args, exc)
        print(f'robot-calib {args.verb}: error: cannot write into {_folder_of(args)}: '
              f'{exc.strerror or os.strerror(exc.errno)} (nothing was left half-written; free '
              'space there or write elsewhere)', file=sys.stderr)
        return _EXIT_BAD_INPUT
    except Exception as exc:  # noqa: B902 - every failure ends in one line, no traceback
        return _failure(args, exc)


_DISK_FULL = (errno.ENOSPC, errno.EDQUOT, errno.EROFS)
"""Write errors of the environment, not of the input: a full disk, a quota, a read-only mount."""


def _folder_of(args: argparse.Namespace) -> str:
    """Return the folder a verb writes into: its output folder, or a bag's parent folder."""
    out = Path(getattr(args, 'out', None) or '.')
    return str(out if args.verb in ('replay', 'mismatch', 'fleet') else out.parent)


def _failure(args: argparse.Namespace, exc: Exception) -> int:
    """Print the one line that ends a failed verb and return its exit status."""
    message = ' '.join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, KeyError) and message.startswith("'"):
        message = message.strip("'")
    if isinstance(exc, _bad_input_types()):
        print(f'robot-calib {args.verb}: error: {message}', file=sys.stderr)
        return _EXIT_BAD_INPUT
    print(f'robot-calib {args.verb}: internal error: {type(exc).__name__}: {message}',
          file=sys.stderr)
    return 1


def entry() -> None:
    """
    Run :func:`main` as the ``robot-calib`` command and exit with its status.

    Every output file is closed and moved into place before ``main`` returns, and
    worker pools and Ray are shut down by their verbs; what is left is the
    interpreter's teardown, freeing every module and array one by one (0.3-0.7 s
    after a replay, a third of a short bag's run). So the buffered streams and
    log handlers are flushed and the process ends at once.
    """
    code = main()
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == '__main__':
    entry()
