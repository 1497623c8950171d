# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The contract between a method's core and the two ways it runs: a live node and replay.

A :class:`Pipeline` names its inputs (default topic and sample kind), its
outputs (topic, message type, QoS), and turns input samples into output
samples. It never imports rclpy or message types: the live node
(:mod:`robot_calib.nodes.base`) and offline replay (:mod:`robot_calib.replay`)
both convert messages with :mod:`robot_calib.codec` and drive the very
same pipeline object, so a bag replayed offline gives the messages the node
would publish live.

Input validation common to every method lives here: samples with non-finite
or physically implausible fields (:mod:`robot_calib.pipelines.validation`),
stamps that go backwards or repeat, samples coming impossibly fast, gaps and
clock jumps are counted per reason (``summary()['inputs']``); a method adds
its own reasons with :meth:`reject`.
"""

from __future__ import annotations

import abc
from collections import defaultdict
from dataclasses import dataclass, replace
from typing import Any, Callable, ClassVar, Optional

from robot_calib.core import frames, types as T
from robot_calib.core.jsonable import jsonable
from robot_calib.core.notes import InputNotes
from robot_calib.core.params import to_flat
from robot_calib.pipelines.stack_export import StackFiles
from robot_calib.pipelines.validation import RateGuard, sample_problem, UNCHECKED

CLOCK_JUMP_SAMPLES = 5
"""Samples in a row continuing from a stamp far off the time line that mean the clock jumped."""


@dataclass(frozen=True)
class InputSpec:
    """One input: ``key`` names it in :meth:`Pipeline.process`, ``topic`` is the default topic."""

    key: str
    topic: str
    kind: str
    optional: bool = False


@dataclass(frozen=True)
class OutputSpec:
    """
    One output: topic (relative, as the node publishes it), sample kind and QoS.

    ``qos`` is ``'default'`` (reliable, volatile, depth 10), ``'latched'``
    (reliable, transient local, depth 1), ``'sensor'`` (best effort, depth 5) or
    ``'tf'`` (reliable, volatile, depth 100: what tf2's broadcaster offers).
    """

    key: str
    topic: str
    kind: str
    qos: str = 'default'


Output = tuple[str, Any]
"""An output: (output key, core sample)."""


class Pipeline(abc.ABC):
    """
    Base class of a method's pipeline; subclasses set the class variables and override hooks.

    Subclasses implement :meth:`handle` (one accepted sample in, outputs out) and
    may override :meth:`finish`, :meth:`method_summary`, :meth:`artifacts` and
    :meth:`plot`.
    """

    name: ClassVar[str] = ''
    params_type: ClassVar[type] = object
    inputs: ClassVar[tuple[InputSpec, ...]] = ()
    outputs: ClassVar[tuple[OutputSpec, ...]] = ()
    max_gap: ClassVar[float] = 1.0
    """Seconds between samples of one input above which a gap is counted (s)."""
    artifact_names: ClassVar[tuple[str, ...]] = ()
    """Files :meth:`artifacts` writes (a node checks its ``output_dir`` when there are any)."""
    clock_jump: ClassVar[float] = 60.0
    """A step ahead between samples of one input longer than this is a clock jump (s)."""
    live_params: ClassVar[tuple[str, ...]] = ()
    """Parameters :meth:`apply_params` takes while running; a node makes the others read-only."""
    refusable: ClassVar[tuple[str, ...]] = ()
    """Inputs :meth:`refusal` may turn away unread (a replay then need not decode them)."""

    def __init__(self, params: Any = None, log: Optional[Callable[[str, str], None]] = None):
        """Create the pipeline with a params instance (defaults when None) and a logger."""
        self.params = params if params is not None else self.params_type()
        self._log = log
        self._last_t: dict[str, float] = {}
        self._pending: dict[str, tuple[str, list]] = {}
        self._shift: dict[str, float] = {}
        self._jumps: list[tuple[float, float]] = []
        self._rate: dict[str, RateGuard] = {}
        self._kinds = {spec.key: spec.kind for spec in self.inputs}
        self.counts: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
        self.n_outputs: dict[str, int] = defaultdict(int)
        self.static_transforms: dict[tuple[str, str], T.StaticTransform] = {}
        self.recording = ''
        """What the data came from (bag paths, or live topics), for exported files' headers."""
        self._same_frame_warned = False
        self._notes_said = 0
        self.own_notes = InputNotes()
        """Standing warnings about the inputs found here (dense scans thinned)."""
        self._notes_logged: set[str] = set()

    # -- logging ---------------------------------------------------------------------------
    def log(self, level: str, message: str) -> None:
        """Log ``message`` at ``level`` ('debug', 'info', 'warn', 'error')."""
        if self._log is not None:
            self._log(level, message)

    # -- input bookkeeping -----------------------------------------------------------------
    def reject(self, key: str, reason: str) -> list:
        """Count one rejected sample of input ``key`` for ``reason``; returns no outputs."""
        self.counts[key]['rejected'] += 1
        self.counts[key]['rejected_' + reason] += 1
        return []

    def refusal(self, key: str) -> str:
        """Return why input ``key`` (one of :attr:`refusable`) is not used now; '' when it is."""
        return ''

    def refuse(self, key: str, reason: str) -> list:
        """
        Count one sample of input ``key`` turned away unread (unchecked) for ``reason``.

        The input's time line starts again when it is used again (no gap or
        clock jump counted against the samples before).
        """
        self.counts[key]['read'] += 1
        self._last_t.pop(key, None)
        self._pending.pop(key, None)
        return self.reject(key, reason)

    def process(self, key: str, sample: Any) -> list[Output]:
        """
        Validate one sample of input ``key`` and hand it to :meth:`handle`.

        Rejected and counted by reason: non-finite and physically implausible
        values (:func:`validation.sample_problem`), repeated stamps, stamps going
        backwards, stray stamps far ahead (``clock_jump``) and samples coming
        impossibly fast for their kind (``implausible_rate``). A clock jump is
        never integrated: see :meth:`_off_time_line` and :meth:`_clock_jumped`.
        """
        return self.process_checked(key, sample, UNCHECKED)

    def process_checked(self, key: str, sample: Any, problem: Any) -> list[Output]:
        """
        Do what :meth:`process` does, given ``problem = validation.sample_problem(sample)``.

        Replay checks each decoded sample once for all the nodes reading it; the
        counts, stamp order, rate and clock jumps are still every node's own.
        With ``problem`` :data:`validation.UNCHECKED` the sample is checked here.
        """
        if isinstance(sample, T.StaticTransform):
            self.static_transforms[(sample.parent, sample.child)] = sample
            self.on_static_transform(sample)
            return []
        if self.refusable and key in self.refusable:
            reason = self.refusal(key)
            if reason:
                return self.refuse(key, reason)
        counts = self.counts[key]
        counts['read'] += 1
        if problem is not None:
            if problem is UNCHECKED:
                problem = sample_problem(sample)
            if problem is not None:
                return self.reject(key, problem)
        if self._shift:
            shift = self._shift.get(key)
            if shift is not None:
                sample = replace(sample, t=sample.t + shift)
        t = sample.t
        last = self._last_t.get(key)
        if last is not None:
            step = t - last
            if not (0.0 < step <= self.max_gap and step <= self.clock_jump):
                if step == 0.0:
                    return self.reject(key, 'duplicate_stamp')
                if -self.max_gap <= step < 0.0:
                    return self.reject(key, 'out_of_order')
                if step < 0.0 or step > self.clock_jump:
                    return self._off_time_line(key, sample, last)
                if step > self.max_gap:
                    counts['gaps'] += 1
            if self._pending:
                self._pending.pop(key, None)  # the time line goes on: those were stray stamps
        return self._accept(key, sample, counts, t)

    def _accept(self, key: str, sample: Any, counts: Optional[dict] = None,
                t: Optional[float] = None) -> list[Output]:
        """
        Check the rate of an in-order sample and hand it to :meth:`handle`.

        ``counts`` is ``self.counts[key]`` and ``t`` is ``sample.t`` (s) when the
        caller has them.
        """
        guard = self._rate.get(key)
        if guard is None:
            guard = self._rate[key] = RateGuard(self._kinds.get(key, ''))
        if t is None:
            t = sample.t
        if not guard.allow(t):
            return self.reject(key, 'implausible_rate')
        self._last_t[key] = t
        c = self.counts[key] if counts is None else counts
        rejected = c['rejected']
        if isinstance(sample, T.ScanSample) and sample.ranges.size > frames.MAX_BEAMS:
            sample = self._thinned(key, sample, c)
        outs = self.handle(key, sample)
        notes = self.input_notes()
        if notes is not None and notes.version != self._notes_said:
            self._say_notes(notes)
        if c['rejected'] == rejected:  # the method did not turn it down either
            c['accepted'] += 1
        if outs:
            n_outputs = self.n_outputs
            for out_key, _ in outs:
                n_outputs[out_key] += 1
        return outs

    def _off_time_line(self, key: str, sample: Any, last: float) -> list[Output]:
        """
        Hold a sample far from the time line until more samples confirm that the clock jumped.

        A stamp more than :attr:`max_gap` behind the last accepted one, or more
        than :attr:`clock_jump` ahead of it, is a stray stamp or a clock jump.
        It is rejected (``out_of_order`` behind, ``clock_jump`` ahead) unless
        :data:`CLOCK_JUMP_SAMPLES` samples in a row continue from it (each within
        :attr:`max_gap` of the one before): then the clock did jump, and those
        samples are taken back from the rejections and used.
        """
        reason = 'out_of_order' if sample.t < last else 'clock_jump'
        held = self._pending.get(key)
        if held and held[0] == reason and 0.0 < sample.t - held[1][-1].t <= self.max_gap:
            held[1].append(sample)
        else:
            held = self._pending[key] = (reason, [sample])
        samples = held[1]
        if len(samples) < CLOCK_JUMP_SAMPLES:
            return self.reject(key, reason)
        del self._pending[key]
        counts = self.counts[key]
        for name in ('rejected', 'rejected_' + reason):
            counts[name] -= len(samples) - 1
            if not counts[name]:
                del counts[name]
        outs: list[Output] = []
        for s in self._clock_jumped(key, last, samples):
            outs += self._accept(key, s)
        return outs

    def _clock_jumped(self, key: str, last: float, samples: list) -> list:
        """
        Report a clock jump of input ``key`` and return ``samples`` moved onto the time line.

        From now on the input's stamps are shifted so that the jump becomes a gap
        of exactly :attr:`clock_jump` seconds, which every method treats as a gap
        (nothing is integrated across it, time lines restart). Another input
        jumping by the same amount (within :attr:`max_gap`) gets the same shift,
        so the inputs stay aligned. Outputs keep the original header stamps
        (``stamp_ns``); times inside the method and its summary are the shifted
        ones.
        """
        jump = samples[0].t - last
        change = next((c for j, c in self._jumps if abs(j - jump) <= self.max_gap),
                      self.clock_jump - jump)
        if len(self._jumps) < 16:
            self._jumps.append((jump, change))
        self._shift[key] = self._shift.get(key, 0.0) + change
        self.counts[key]['clock_jumps'] += 1
        self.log('warn', f'{key}: clock jumped {"ahead" if jump > 0 else "back"} by '
                 f'{abs(jump):.3f} s: taken as a gap of {jump + change:.1f} s (nothing '
                 'integrated across it)')
        return [replace(s, t=s.t + change) for s in samples]

    def _thinned(self, key: str, scan: T.ScanSample, counts: dict) -> T.ScanSample:
        """Return a dense scan thinned to :data:`frames.MAX_BEAMS` beams at most; say so once."""
        out = frames.thinned(scan)
        counts['thinned'] += 1
        n = scan.ranges.size
        note = (f'{key}: scans of {n} beams thinned to {out.ranges.size} (one beam in '
                f'{-(-n // frames.MAX_BEAMS)} kept over the whole field of view; at most '
                f'{frames.MAX_BEAMS} beams are used)')
        if key not in self.own_notes.by_key:
            self.log('warn', note)
        self.own_notes.say(key, note)
        return out

    def _say_notes(self, notes: InputNotes) -> None:
        """Log the input warnings said since last time (each once)."""
        self._notes_said = notes.version
        said = self._notes_logged
        for message in notes.messages():
            if message not in said and len(said) < 100:
                said.add(message)
                self.log('warn', message)

    def input_warnings(self) -> list[str]:
        """
        Return the standing warnings about the inputs (frames, odometry); [] when none.

        Said in ``summary.json`` (``input_warnings``) and, by a live node, on
        ``/diagnostics`` (level WARN).
        """
        notes = self.input_notes()
        return self.own_notes.messages() + (notes.messages() if notes is not None else [])

    # -- hooks -----------------------------------------------------------------------------
    def input_notes(self) -> Optional[InputNotes]:
        """Return the method's standing warnings about its inputs, or None (none kept)."""
        return None

    @abc.abstractmethod
    def handle(self, key: str, sample: Any) -> list[Output]:
        """Process one accepted sample; return outputs."""

    def apply_params(self, params: Any) -> None:
        """Take new parameters that differ from the current ones only in :attr:`live_params`."""
        self.params = params

    def active_outputs(self) -> tuple[OutputSpec, ...]:
        """
        Return the outputs this instance publishes (a node advertises only these).

        ``/tf`` outputs (kind ``tf``) only with a ``publish_tf`` parameter set.
        """
        if getattr(self.params, 'publish_tf', False):
            return self.outputs
        return tuple(o for o in self.outputs if o.kind != 'tf')

    def correction_tf(self, corrected: T.OdomSample, odom: T.OdomSample) -> list[Output]:
        """
        Return the ``/tf`` output of the correction from ``corrected``'s frame to ``odom``'s.

        ``corrected`` is a drift-corrected pose (in the map frame) and ``odom`` the
        odometry input it was made from; nothing without ``publish_tf``, and
        nothing (one warning) when both name the same frame.
        """
        if not getattr(self.params, 'publish_tf', False):
            return []
        if corrected.frame_id == (odom.frame_id or 'odom'):
            if not self._same_frame_warned:
                self._same_frame_warned = True
                self.log('warn', f'publish_tf: the corrected pose and the odometry are both in '
                         f'{corrected.frame_id!r}: no correction published on /tf '
                         '(set map_frame)')
            return []
        return [('tf', [frames.correction_transform(corrected, odom)])]

    def on_static_transform(self, transform: T.StaticTransform) -> None:
        """React to a static transform (e.g. the IMU mounting); default: keep it."""

    def finish(self) -> list[Output]:
        """Flush at the end of a recording or at shutdown; return final outputs."""
        return []

    def close(self) -> list[Output]:
        """Return :meth:`finish`'s final outputs, counted with the others in the summary."""
        outs = self.finish()
        for out_key, _ in outs:
            self.n_outputs[out_key] += 1
        return outs

    def method_summary(self) -> dict[str, Any]:
        """Return method-specific results for ``summary.json`` (estimates, corrections...)."""
        return {}

    @staticmethod
    def headline(summary: dict[str, Any]) -> dict[str, Any]:
        """
        Return what a fleet table tracks from this node's ``summary.json`` section.

        Numbers by name (an estimate's standard deviation as ``<name>_std``), plus
        ``verdict`` (text) and ``alerts`` (a count) where the method has them.
        """
        return {}

    def artifacts(self) -> dict[str, str]:
        """Return extra files to write next to the replay output: {file name: text}."""
        return {}

    def static_mounting(self, frame: Optional[str],
                        base: str) -> Optional[T.StaticTransform]:
        """Return the static transform ``base`` -> ``frame`` seen so far (through chains)."""
        if not frame:
            return None
        tree = frames.StaticTree()
        for tf in self.static_transforms.values():
            tree.add(tf)
        return tree.mounting(frame, base)

    def stack_export(self) -> StackFiles:
        """
        Return the results in the form the robot's own stack takes (:mod:`.stack_export`).

        Written into a ``stack/`` folder; each file's header names the node and
        :attr:`recording`. None by default.
        """
        return StackFiles()

    def plot(self, out_dir: str) -> list[str]:
        """Draw report plots (PNG) into ``out_dir``; return the file names written."""
        return []

    # -- summary ---------------------------------------------------------------------------
    def summary(self) -> dict[str, Any]:
        """Return the JSON-ready summary: parameters, inputs read/rejected, outputs, results."""
        out = {
            'params': {k: jsonable(v) for k, v in to_flat(self.params).items()},
            'inputs': {k: dict(v) for k, v in self.counts.items()},
            'outputs': dict(self.n_outputs),
            **{k: jsonable(v) for k, v in self.method_summary().items()},
        }
        warnings = self.input_warnings()
        if warnings:
            out['input_warnings'] = warnings
        return out
