# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
A thin rclpy node around a :class:`robot_calib.pipelines.base.Pipeline`.

Subscriptions receive serialized messages (``raw=True``), converted by the same
code replay uses; outputs are serialized the same way and published as bytes.
A callback never raises: a message that cannot be decoded or processed is
counted and logged (throttled), and the node goes on.
"""

from __future__ import annotations

from functools import partial
import importlib
from pathlib import Path
import sys
import time
from typing import Any, Optional

import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, qos_profile_sensor_data, QoSProfile,
                       ReliabilityPolicy)

from robot_calib.core.params import ParamError
from robot_calib.io import bags, convert
from robot_calib.nodes.ros_params import declare_params
from robot_calib.pipelines.base import KINDS, Pipeline

LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
DEFAULT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
_QOS = {'latched': LATCHED_QOS, 'default': DEFAULT_QOS, 'sensor': qos_profile_sensor_data}


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
        params = declare_params(self, pipeline_cls.params_type)
        self.declare_parameter('output_dir', '.')
        self.pipeline = pipeline_cls(params, log=self._log)
        self.callback_seconds: list[float] = []
        self.undecodable = 0
        self._errors = 0
        self._pubs = {}
        for spec in pipeline_cls.outputs:
            msgtype = KINDS[spec.kind][0]
            cls = message_class(msgtype)
            self._pubs[spec.key] = self.create_publisher(cls, spec.topic, _QOS[spec.qos])
        self._subs = []
        for spec in pipeline_cls.inputs:
            msgtype = KINDS[spec.kind][0]
            cls = message_class(msgtype)
            if cls is None:
                self.get_logger().warn(f'{msgtype} is not installed: not subscribing to '
                                       f'{spec.topic} (set the matching parameter instead)')
                continue
            qos = LATCHED_QOS if spec.kind == 'tf_static' else qos_profile_sensor_data
            self._subs.append(self.create_subscription(
                cls, spec.topic, partial(self._on_message, spec.key, msgtype), qos, raw=True))
        self.get_logger().info(
            f'{pipeline_cls.name} ready (mode {getattr(params, "mode", "n/a")}): '
            f'inputs {[s.topic for s in pipeline_cls.inputs]}, '
            f'outputs {[s.topic for s in pipeline_cls.outputs]}')

    def _log(self, level: str, message: str) -> None:
        logger = self.get_logger()
        {'debug': logger.debug, 'info': logger.info, 'warn': logger.warn,
         'error': logger.error}.get(level, logger.info)(message)

    def _on_message(self, key: str, msgtype: str, data: bytes) -> None:
        start = time.perf_counter()
        try:
            fast = bags.FAST_DECODERS.get(msgtype)
            if fast is not None and len(data) > 1 and data[1] == 1:  # little-endian CDR
                samples = [fast(data)]
            else:
                samples = convert.deserialize(msgtype, data, self.get_clock().now().nanoseconds)
        except Exception as exc:  # noqa: B902 - a bad message must never stop the node
            self.undecodable += 1
            self.pipeline.reject(key, 'undecodable')
            self.get_logger().warn(f'cannot decode a {msgtype} on {key}: {exc}',
                                   throttle_duration_sec=5.0)
            return
        for sample in samples:
            try:
                self.publish(self.pipeline.process(key, sample))
            except Exception as exc:  # noqa: B902 - count, log and keep running
                self._errors += 1
                self.pipeline.reject(key, 'processing_error')
                self.get_logger().error(f'{key}: {type(exc).__name__}: {exc}',
                                        throttle_duration_sec=5.0)
        self.callback_seconds.append(time.perf_counter() - start)
        if len(self.callback_seconds) > 100000:
            del self.callback_seconds[:50000]

    def publish(self, outputs: list) -> None:
        """Serialize and publish pipeline outputs."""
        for key, sample in outputs:
            _, raw = bags.serialize(sample)
            self._pubs[key].publish(raw)

    def callback_p99(self) -> float:
        """Return the 99th percentile callback time (s) so far."""
        if not self.callback_seconds:
            return 0.0
        return float(np.percentile(self.callback_seconds, 99))

    def finish(self) -> None:
        """Flush the pipeline and write its artifacts into ``output_dir``."""
        try:
            self.publish(self.pipeline.finish())
        except Exception as exc:  # noqa: B902 - shutting down; report and go on
            self.get_logger().error(f'finish failed: {exc}')
        artifacts = self.pipeline.artifacts()
        if artifacts:
            out_dir = Path(self.get_parameter('output_dir').value)
            out_dir.mkdir(parents=True, exist_ok=True)
            for name, text in artifacts.items():
                tmp = out_dir / f'.{name}.partial'
                tmp.write_text(text)
                tmp.replace(out_dir / name)
                self.get_logger().info(f'wrote {out_dir / name}')


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
        print(f'{pipeline_cls.name}: {exc}', file=sys.stderr)
        code = 2
    finally:
        if node is not None:
            node.finish()
            node.destroy_node()
        rclpy.try_shutdown()
    return code
