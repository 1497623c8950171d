# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Which nodes run on which topics: remaps split into node and bag sides, inputs checked, runs made.

:func:`plan` turns the request (nodes or None for every registered one whose
required inputs are in the bags, remap rules, parameters) and the open bags
into a :class:`Plan`: one :class:`NodeRun` per selected node, the nodes
skipped with the reason, and the bag topics as the nodes see them.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from typing import Any, Callable, Optional, Sequence

from robot_calib import codec, methods
from robot_calib.core.series import Reservoir
from robot_calib.io.bags import BagError, BagSet, normalize_topic
from robot_calib.pipelines.base import Pipeline
from robot_calib.replay.config import (check_override_nodes, NodeSpec, params_for, ReplayError,
                                       resolve_node)

BagTopics = dict[str, tuple[str, int]]
"""Topic (after bag-side remaps) -> (message type, message count)."""


class NodeRun:
    """A pipeline being replayed: its routes, outputs, timing and errors."""

    def __init__(self, name: str, cls: type, params: Any):
        """Create the pipeline with ``params``; its log lines are kept (at most 50)."""
        self.name = name
        self.cls = cls
        self.logs: list[str] = []
        self.log_counts: dict[str, int] = defaultdict(int)
        self.pipeline: Pipeline = cls(params, log=self._log)
        self.inputs: dict[str, str] = {}  # key -> topic
        self.outputs: dict[str, tuple[str, str, bool]] = {}  # key -> (topic, msgtype, latched)
        self.notes: list[str] = []
        self.times = Reservoir()
        """Seconds per input message: count, sum and a sample for percentiles."""
        self.errors: dict[str, int] = defaultdict(int)
        self.first_errors: list[str] = []
        self.tf_key = 'tf_static'
        self.tf_topic = '/tf_static'  # where its static transforms come from (remaps applied)
        self.errors_key = 'errors'

    def _log(self, level: str, message: str) -> None:
        self.log_counts[level] += 1
        if len(self.logs) < 50:
            self.logs.append(f'[{level}] {message}')

    def error(self, where: str, exc: BaseException) -> None:
        """Count an error of stage ``where``; keep the first five as text."""
        self.errors[where] += 1
        if len(self.first_errors) < 5:
            self.first_errors.append(f'{where}: {type(exc).__name__}: '
                                     f'{" ".join(str(exc).split())}')


@dataclass
class Plan:
    """What runs: the node runs, the nodes skipped (name -> reason) and the topic maps."""

    runs: list[NodeRun]
    skipped: dict[str, str]
    topic_of_stream: dict[int, str]
    """``id(stream)`` -> the topic its messages are seen on (bag-side remaps applied)."""
    bag_topics: BagTopics
    remaps: dict[str, str]


def _candidates(nodes: Optional[Sequence[NodeSpec]]) -> tuple[list, dict[str, str]]:
    """Return the (name, class) of the nodes to consider and those skipped already."""
    skipped: dict[str, str] = {}
    if nodes is not None:
        candidates = [resolve_node(n) for n in nodes]
        names = [n for n, _ in candidates]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ReplayError(f'node(s) {dup} given twice in --nodes')
        return candidates, skipped
    candidates = []
    for name in methods.REGISTRY:
        if name not in methods.available():
            skipped[name] = 'not installed (module missing)'
            continue
        try:
            candidates.append(resolve_node(name))
        except ReplayError as exc:
            skipped[name] = str(exc)
    return candidates, skipped


def _split_remaps(rules: list[tuple[str, str]], candidates: list, raw_topics: Any
                  ) -> tuple[dict[str, str], dict[str, str]]:
    """Return (node-side, bag-side) remaps: a rule's FROM is a node topic or a bag topic."""
    node_topics = set()
    for _, cls in candidates:
        node_topics.update(normalize_topic(s.topic) for s in cls.inputs)
        node_topics.update(normalize_topic(s.topic) for s in cls.outputs)
    node_map: dict[str, str] = {}
    bag_map: dict[str, str] = {}
    for src, dst in rules:
        if src in node_topics:
            node_map[src] = dst
        elif src in raw_topics:
            bag_map[src] = dst
        else:
            raise ReplayError(
                f'--remap {src}:={dst}: {src} is neither a topic of the nodes '
                f'({", ".join(sorted(node_topics)) or "none"}) nor a topic in the bag(s) '
                f'({", ".join(sorted(raw_topics)) or "none"})')
    for src, dst in bag_map.items():
        # two recorded streams poured into one topic: only static transforms add up
        if dst in raw_topics and dst not in bag_map and \
                raw_topics[dst][0] != 'tf2_msgs/msg/TFMessage':
            raise ReplayError(f'--remap {src}:={dst}: the bag(s) already hold {dst}; its '
                              f'messages and those of {src} would be merged into one stream '
                              f'(remap {dst} elsewhere too, or drop this remap)')
    return node_map, bag_map


def _bag_topics(bagset: BagSet, bag_map: dict[str, str]) -> tuple[dict[int, str], BagTopics]:
    """Return the topic of every stream and the bag topics, after bag-side remaps."""
    topic_of_stream = {id(s): bag_map.get(s.topic, s.topic) for s in bagset.streams}
    bag_topics: BagTopics = {}
    for s in bagset.streams:
        t = topic_of_stream[id(s)]
        prev = bag_topics.get(t)
        if prev is not None and prev[0] != s.msgtype:
            raise BagError(f'topic {t} has two types in the bag(s): {prev[0]} and '
                           f'{s.msgtype}; expected one type per topic')
        bag_topics[t] = (s.msgtype, (prev[1] if prev else 0) + s.count)
    return topic_of_stream, bag_topics


def check_inputs(cls: type, topic_of: Any, bag_topics: dict[str, tuple[str, int]]
                 ) -> tuple[Optional[str], dict[str, str], list[str]]:
    """Return (reason it cannot run or None, {key: topic} of inputs present, notes)."""
    present: dict[str, str] = {}
    notes = []
    for spec in cls.inputs:
        if spec.kind == 'tf_static':
            continue
        topic = topic_of(spec.topic)
        expected = codec.KINDS[spec.kind].msgtype
        have = bag_topics.get(topic)
        if have is None:
            if not spec.optional:
                return (f'needs {topic} ({expected}), not in the bag(s)', present, notes)
            notes.append(f'optional input {topic} ({expected}) not in the bag(s)')
            continue
        if not codec.accepts(spec.kind, have[0]):
            msg = f'{topic} is {have[0]} in the bag(s), expected {expected}'
            if not spec.optional:
                return (msg, present, notes)
            notes.append('optional input ignored: ' + msg)
            continue
        present[spec.key] = topic
    return None, present, notes


NOT_PAIRED = ('ground_truth', 'groundtruth', 'filtered', 'fused', 'corrected')
"""Bag topics named like these are never read for a node's input by their type alone."""


def _auto_inputs(candidates: list, node_map: dict[str, str], bag_topics: BagTopics
                 ) -> dict[str, str]:
    """
    Return node input topic -> bag topic for inputs the bag holds under another name.

    An input whose topic is neither in the bags nor remapped reads the bags' one
    topic of an accepted type (``/imu/data`` for ``imu``), unless that topic is
    any node's output, named like an estimate or a ground truth
    (:data:`NOT_PAIRED`) or read already for another input; an optional input
    only when the bag topic ends with its name (``/wheel/odom`` for ``odom``).
    With two or more such topics it stays unpaired (``--remap`` chooses).
    Required inputs are paired first.
    """
    outputs = {normalize_topic(s.topic) for _, cls in candidates for s in cls.outputs}
    auto: dict[str, str] = {}
    specs = [s for _, cls in candidates for s in cls.inputs if s.kind != 'tf_static']
    for spec in sorted(specs, key=lambda s: s.optional):
        topic = normalize_topic(spec.topic)
        if topic in node_map or topic in bag_topics or topic in auto:
            continue
        found = [t for t, (msgtype, _) in bag_topics.items()
                 if codec.accepts(spec.kind, msgtype) and t not in outputs
                 and t not in auto.values() and not any(w in t.lower() for w in NOT_PAIRED)
                 and (not spec.optional or t.endswith(topic))]
        if len(found) == 1:
            auto[topic] = found[0]
    return auto


def _select(candidates: list, topic_of: Callable[[str], str], bag_topics: BagTopics,
            explicit: bool, skipped: dict[str, str], bag_names: str) -> list[tuple]:
    """Return (name, class, inputs present, notes) of the nodes whose inputs are there."""
    selected = []
    for name, cls in candidates:
        reason, present, notes = check_inputs(cls, topic_of, bag_topics)
        if reason is not None:
            if explicit:
                raise ReplayError(f'node {name} {reason}; bag topics: '
                                  f'{", ".join(sorted(bag_topics)) or "none"} '
                                  '(use --remap NODE_TOPIC:=BAG_TOPIC)')
            skipped[name] = reason
            continue
        selected.append((name, cls, present, notes))
    if not selected:
        why = '; '.join(f'{n}: {r}' for n, r in skipped.items()) or 'no node is installed'
        raise ReplayError(f'no node can run on {bag_names} ({why})')
    return selected


def _check_output_topics(selected: list[tuple], topic_of: Callable[[str], str]) -> None:
    """
    Refuse remaps that put outputs of different topics on one topic (ReplayError).

    A bag topic holds one stream of one type: one of them would be lost or the
    two merged. Outputs that share a topic without the remaps (``/diagnostics``,
    ``/tf``) may still share it.
    """
    first: dict[str, tuple[str, str]] = {}  # topic -> (node output, its topic before remaps)
    for name, cls, *_ in selected:
        for spec in cls.outputs:
            own = normalize_topic(spec.topic)
            topic = topic_of(spec.topic)
            other, other_own = first.setdefault(topic, (f'{name} {spec.key}', own))
            if other_own != own:
                raise ReplayError(f'--remap puts two outputs on {topic}: {other} '
                                  f'({other_own}) and {name} {spec.key} ({own}); one would '
                                  'be lost or both merged; remap them to different topics')


def _make_run(name: str, cls: type, present: dict[str, str], notes: list[str], params: Any,
              topic_of: Callable[[str], str]) -> NodeRun:
    run = NodeRun(name, cls, params)
    run.inputs = present
    run.notes = notes
    for spec in cls.inputs:
        if spec.kind == 'tf_static':
            run.tf_key = spec.key
            run.tf_topic = topic_of(spec.topic)
    for spec in cls.outputs:
        run.outputs[spec.key] = (topic_of(spec.topic), codec.KINDS[spec.kind].msgtype,
                                 spec.qos == 'latched')
    return run


def plan(bagset: BagSet, nodes: Optional[Sequence[NodeSpec]], rules: list[tuple[str, str]],
         file_params: dict[str, dict[str, Any]], by_node: dict[str, dict[str, Any]],
         bag_names: str) -> Plan:
    """Select the nodes that can run on ``bagset`` and set them up; ReplayError otherwise."""
    candidates, skipped = _candidates(nodes)
    node_map, bag_map = _split_remaps(rules, candidates, bagset.topics())
    topic_of_stream, bag_topics = _bag_topics(bagset, bag_map)

    auto = _auto_inputs(candidates, node_map, bag_topics)

    def topic_of(topic: str) -> str:
        t = normalize_topic(topic)
        return node_map.get(t, t)

    def input_of(topic: str) -> str:
        t = normalize_topic(topic)
        return node_map.get(t) or auto.get(t, t)

    selected = _select(candidates, input_of, bag_topics, nodes is not None, skipped, bag_names)
    for name, cls, present, notes in selected:
        for key, topic in present.items():
            source = next((t for t, bag in auto.items() if bag == topic), None)
            if source is not None:
                notes.append(f'input {key} reads {topic}, the only '
                             f'{bag_topics[topic][0]} in the bag(s) ({source} is not there; '
                             f'--remap {source}:=TOPIC chooses another)')
    check_override_nodes(by_node, {n for n, *_ in selected})
    _check_output_topics(selected, topic_of)
    runs = [_make_run(name, cls, present, notes,
                      params_for(name, cls, file_params, by_node.get(name, {})), topic_of)
            for name, cls, present, notes in selected]
    used = {t for _, _, present, _ in selected for t in present.values()}
    auto = {src: dst for src, dst in auto.items() if dst in used}
    return Plan(runs, skipped, topic_of_stream, bag_topics, {**auto, **node_map, **bag_map})
