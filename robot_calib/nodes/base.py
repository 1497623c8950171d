# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
A thin rclpy node around a :class:`robot_calib.pipelines.base.Pipeline`.

Subscriptions receive serialized messages (``raw=True``), converted by the same
code replay uses; outputs are serialized the same way and published as bytes.
A callback never raises: a message that cannot be decoded or processed is
counted and logged (throttled), and the node goes on. Once a second the node
publishes the health of its inputs on ``/diagnostics`` (waiting, stale, every
message rejected and why), and warns when its input is all rejected. A node
that writes files checks its ``output_dir`` before it starts.
"""

from __future__ import annotations

import difflib
from functools import partial
import importlib
import os
from pathlib import Path
import sys
import time
from typing import Any, Optional

import numpy as np
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, qos_profile_sensor_data, QoSProfile,
                       ReliabilityPolicy)

from robot_calib import codec
from robot_calib.core import types as T
from robot_calib.core.params import from_flat, ParamError, to_flat
from robot_calib.nodes.health import input_health, NodeLog, WARN
from robot_calib.nodes.ros_params import declare_params
from robot_calib.pipelines.base import Pipeline
from robot_calib.pipelines.stack_export import FOLDER
from robot_calib.pipelines.validation import restamp_unset

HEALTH_PERIOD = 1.0
"""Seconds between two input-health statuses on /diagnostics."""
STALE_AFTER = 5.0
"""Seconds of silence after which an input that was arriving is reported stale."""

LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
DEFAULT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
TF_STATIC_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                           reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""``/tf_static`` as tf2's listener reads it: every static broadcaster's latched message (with
depth 1, the messages of broadcasters that started earlier would overwrite each other); replay
``--live`` offers a bag's static messages so too, all of them to a late subscriber."""
TF_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                    reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE)
"""``/tf`` as tf2's TransformBroadcaster offers it."""
_QOS = {'latched': LATCHED_QOS, 'default': DEFAULT_QOS, 'sensor': qos_profile_sensor_data,
        'tf': TF_QOS}


def message_class(msgtype: str) -> Optional[type]:
    """Return the rclpy message class of ``pkg/msg/Name``, or None when not installed."""
    pkg, _, name = msgtype.split('/')
    try:
        return getattr(importlib.import_module(f'{pkg}.msg'), name)
    except (ImportError, AttributeError):
        return None


class PipelineNode(Node):
    """
    Run one pipeline live: subscribe its inputs, publish its outputs.

    Besides the method's own parameters the node has ``output_dir`` (where
    artifacts such as the wheel calibration YAML are written at shutdown).
    """

    def __init__(self, pipeline_cls: type[Pipeline], **kwargs: Any):
        """Declare parameters, build the pipeline, and create subscriptions and publishers."""
        super().__init__(pipeline_cls.name, **kwargs)
        self.log = NodeLog(self.get_logger())
        params = declare_params(self, pipeline_cls.params_type, pipeline_cls.live_params)
        self.declare_parameter('output_dir', '.', ParameterDescriptor(
            description='folder where the node writes result files at shutdown',
            read_only=True))
        self._warn_unknown_parameters()
        if pipeline_cls.artifact_names:
            check_output_dir(self.get_parameter('output_dir').value)
        self.pipeline = pipeline_cls(params, log=self._log)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.callback_seconds: list[float] = []
        self.undecodable = 0
        self.restamped = 0
        """Messages whose header stamp was unset (0), stamped at their receive time."""
        self._errors = 0
        self._pubs = {}
        for spec in self.pipeline.active_outputs():
            msgtype = codec.KINDS[spec.kind].msgtype
            cls = message_class(msgtype)
            if cls is None:
                raise ParamError(missing_output_type(spec.topic, msgtype))
            self._pubs[spec.key] = self.create_publisher(cls, spec.topic, _QOS[spec.qos])
        self._subs = []
        for spec in pipeline_cls.inputs:
            msgtype = codec.KINDS[spec.kind].msgtype
            cls = message_class(msgtype)
            if cls is None:
                self.log('warn', f'{msgtype} is not installed: not subscribing to '
                         f'{spec.topic} (set the matching parameter instead; '
                         f'{missing_type_hint(msgtype)})')
                continue
            qos = TF_STATIC_QOS if spec.kind == 'tf_static' else qos_profile_sensor_data
            self._subs.append(self.create_subscription(
                cls, spec.topic, partial(self._on_message, spec.key, msgtype,
                                         decode=codec.decoder(msgtype)), qos, raw=True))
        self._health_pub = self.create_publisher(message_class(codec.KINDS['diagnostics'].msgtype),
                                                 '/diagnostics', DEFAULT_QOS)
        self._health_prev: dict = {}
        self._health_t: Optional[float] = None
        self._kinds = {s.key: s.kind for s in pipeline_cls.inputs}
        self._last_input: dict[str, float] = {}
        self._required = [s.key for s in pipeline_cls.inputs
                          if not s.optional and s.kind != 'tf_static']
        self.create_timer(HEALTH_PERIOD, self._publish_health)
        self.log('info', f'{pipeline_cls.name} ready (mode {getattr(params, "mode", "n/a")}): '
                 f'inputs {[s.topic for s in pipeline_cls.inputs]}, '
                 f'outputs {[s.topic for s in self.pipeline.active_outputs()]}')

    def _log(self, level: str, message: str) -> None:
        """Log for the pipeline: each distinct message at most once every 5 s."""
        self.log(level, message, throttle_s=5.0)

    def _on_set_parameters(self, changed: list) -> SetParametersResult:
        """Check a live parameter change against the params dataclass and apply it."""
        live = set(self.pipeline.live_params)
        mine = {p.name: p.value for p in changed if p.name in live}
        if not mine:
            return SetParametersResult(successful=True)
        try:
            params = from_flat(type(self.pipeline.params),
                               {**to_flat(self.pipeline.params), **mine})
        except ParamError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        self.pipeline.apply_params(params)
        self.log('info', 'parameters applied: ' + ', '.join(f'{k}={v}' for k, v in mine.items()))
        return SetParametersResult(successful=True)

    def _warn_unknown_parameters(self) -> None:
        """Warn (one line) about ``-p`` overrides that name no parameter of this node."""
        given = set(getattr(self, '_parameter_overrides', {}) or {})
        known = set(self._parameters)
        unknown = sorted(given - known)
        if unknown:
            hints = []
            for name in unknown:
                close = difflib.get_close_matches(name, sorted(known), n=2)
                hints.append(f'{name}' + (f' (did you mean {" or ".join(close)}?)'
                                          if close else ''))
            self.log('warn', f'unknown parameter(s) ignored: {", ".join(hints)}')

    def _publish_health(self) -> None:
        """Publish the health of the inputs on /diagnostics; warn when all input is rejected."""
        now = time.monotonic()
        counts = {k: dict(v) for k, v in self.pipeline.counts.items()}
        idle = {k: now - t for k, t in self._last_input.items()}
        period = now - self._health_t if self._health_t is not None else 0.0
        prev = self._health_prev
        level, message, values = input_health(counts, prev, idle,
                                              self._required, STALE_AFTER, period, self._kinds)
        self._health_prev, self._health_t = counts, now
        warnings = self.pipeline.input_warnings()
        if warnings:   # standing facts about the inputs (a frame not in /tf_static...)
            level = max(level, WARN)
            message = '; '.join(([] if message == 'inputs OK' else [message]) + warnings)
            values = list(values) + [(f'input_warning.{i}', w) for i, w in enumerate(warnings)]
        if level == 2:
            self.log('warn', f'{message}: no output until valid input arrives',
                     throttle_s=10.0, key='all_rejected')
        for key, c in counts.items():
            if c.get('rejected_duplicate_joint', 0) > prev.get(key, {}).get(
                    'rejected_duplicate_joint', 0):
                self.log('warn', f'{c["rejected_duplicate_joint"]} {key} message(s) name a '
                         "joint twice and were rejected (which value is the joint's cannot "
                         'be told)', throttle_s=30.0, key='duplicate_joint')
        stamp = self.get_clock().now().nanoseconds
        status = T.DiagnosticStatus(f'{self.get_fully_qualified_name()}: inputs', level, message,
                                    '', tuple(values))
        try:
            _, raw = codec.serialize(T.DiagnosticSample(stamp * 1e-9, (status,), stamp))
            self._health_pub.publish(raw)
        except Exception as exc:  # noqa: B902 - health reporting must never stop the node
            self.log('error', f'cannot publish input health: {exc}', throttle_s=30.0,
                     key='health')

    def _on_message(self, key: str, msgtype: str, data: bytes,
                    decode: Optional[codec.Decode] = None) -> None:
        start = time.perf_counter()
        self._last_input[key] = time.monotonic()
        try:
            decode = decode or codec.decoder(msgtype)
            now = self.get_clock().now().nanoseconds
            samples = decode(data, now)
            if samples and getattr(samples[0], 'stamp_ns', -1) == 0:
                restamped = restamp_unset(samples, now)
                if restamped is not None:  # a driver that leaves header.stamp unset
                    samples = restamped
                    self.restamped += 1
                    self.log('warn', f'{key}: messages without a header stamp (0): their '
                             'receive time is used instead', throttle_s=60.0,
                             key=f'unstamped:{key}')
        except Exception as exc:  # noqa: B902 - a bad message must never stop the node
            self.undecodable += 1
            self.pipeline.reject(key, 'undecodable')
            self.log('warn', f'cannot decode a {msgtype} on {key}: {exc}', throttle_s=5.0,
                     key=f'decode:{key}')
            return
        for sample in samples:
            try:
                self.publish(self.pipeline.process(key, sample))
            except Exception as exc:  # noqa: B902 - count, log and keep running
                self._errors += 1
                self.pipeline.reject(key, 'processing_error')
                self.log('error', f'{key}: {type(exc).__name__}: {exc}', throttle_s=5.0,
                         key=f'error:{key}')
        self.callback_seconds.append(time.perf_counter() - start)
        if len(self.callback_seconds) > 100000:
            del self.callback_seconds[:50000]

    def publish(self, outputs: list) -> None:
        """Serialize and publish pipeline outputs."""
        for key, sample in outputs:
            _, raw = codec.serialize(sample)
            self._pubs[key].publish(raw)

    def callback_p99(self) -> float:
        """Return the 99th percentile callback time (s) so far."""
        if not self.callback_seconds:
            return 0.0
        return float(np.percentile(self.callback_seconds, 99))

    def finish(self) -> None:
        """
        Flush the pipeline and write its artifacts into ``output_dir``.

        The final outputs are published only while the ROS context is still up
        (after Ctrl-C or SIGTERM it is not: they are then only logged); the
        artifacts are written in any case, each atomically.
        """
        try:
            final = self.pipeline.close()
        except Exception as exc:  # noqa: B902 - shutting down; report and go on
            self.log('error', f'finish failed: {type(exc).__name__}: {exc}')
            final = []
        if final and self.context.ok():
            try:
                self.publish(final)
            except Exception as exc:  # noqa: B902 - the context may close under us
                self.log('warn', f'final outputs not published: {exc}')
        try:
            artifacts = self.pipeline.artifacts()
        except Exception as exc:  # noqa: B902 - report and go on
            self.log('error', f'artifacts failed: {type(exc).__name__}: {exc}')
            artifacts = {}
        out_dir = Path(self.get_parameter('output_dir').value)
        if artifacts:
            self._write_files(out_dir, artifacts)
        if self.pipeline.artifact_names:
            self._write_stack(out_dir / FOLDER)

    def _write_files(self, out_dir: Path, files: dict) -> None:
        """Write ``{name: text}`` into ``out_dir``, each atomically; log what was written."""
        try:
            out_dir.mkdir(parents=True, exist_ok=True)
            for name, text in files.items():
                tmp = out_dir / f'.{name}.partial'
                tmp.write_text(text)
                if name.endswith('.sh'):
                    os.chmod(tmp, 0o755)
                tmp.replace(out_dir / name)
                self.log('info', f'wrote {out_dir / name}')
        except OSError as exc:
            self.log('error', f'cannot write into {out_dir}: {exc.strerror or exc}')

    def _write_stack(self, folder: Path) -> None:
        """Write the results in the form the robot's stack takes into ``folder`` (stack/)."""
        topics = ', '.join(sorted({sub.topic_name for sub in self._subs}))
        until = time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())
        self.pipeline.recording = f'live topics {topics} (node {self.get_name()}, until {until})'
        try:
            export = self.pipeline.stack_export()
        except Exception as exc:  # noqa: B902 - report and go on
            self.log('error', f'stack export failed: {type(exc).__name__}: {exc}')
            return
        for why in export.withheld:
            self.log('info', f'{FOLDER}/ {why}')
        files = {n: t for n, t in export.files.items() if Path(n).name == n}
        if files:
            self._write_files(folder, files)


def missing_type_hint(msgtype: str) -> str:
    """Return how to get the message package of ``msgtype`` (one clause, no full stop)."""
    if msgtype.startswith('tf2_msgs/'):
        return ('/tf and /tf_static need it: tools/build_tf2_msgs.sh builds it into the virtual '
                'environment where cmake and a C/C++ compiler exist (`make venv` runs it), or '
                'source a ROS 2 installation')
    return 'install its message package'


def missing_output_type(topic: str, msgtype: str) -> str:
    """Return the one-line reason a node cannot publish ``topic``: ``msgtype`` is not installed."""
    return f'cannot publish {topic}: {msgtype} is not installed ({missing_type_hint(msgtype)})'


def check_output_dir(path: str) -> None:
    """Raise ParamError (one line) when ``path`` is not a folder this process can write into."""
    out = Path(path)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ParamError(f'output_dir {path} cannot be created ({exc.strerror or exc}); '
                         'expected a writable folder') from None
    if not out.is_dir() or not os.access(out, os.W_OK | os.X_OK):
        raise ParamError(f'output_dir {path} is not a writable folder; expected a writable '
                         'folder')


def run(pipeline_cls: type[Pipeline], args: Optional[list[str]] = None) -> int:
    """Run a pipeline node until shutdown (the Jazzy ``main()`` shape); return an exit code."""
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = PipelineNode(pipeline_cls)
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ParamError as exc:
        print(f'{pipeline_cls.name}: error: {exc}', file=sys.stderr)
        code = 2
    finally:
        if node is not None:
            node.finish()
            node.destroy_node()
        try:
            rclpy.try_shutdown()
        except Exception:  # noqa: B902 - the signal handler may have shut the context down
            pass
    return code
