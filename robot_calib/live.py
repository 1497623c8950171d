# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
``robot-calib replay --live``: publish bags through rclpy at the recorded rate, with /clock.

Like ``ros2 bag play``: every topic whose message type is installed is
published on its own name (after ``--remap FROM:=TO`` on bag topics) as the
serialized bytes from the bag (ROS 1 messages are converted to ROS 2 CDR
first), paced by the bag receive times divided by ``rate``; ``/clock``
(rosgraph_msgs/Clock) carries the bag time so nodes can run with
``use_sim_time``. Topics recorded as transient-local are published latched,
and ``/tf_static`` latched with room for every static message of the bag
(a node started later receives them all, as from tf2's static broadcasters).
"""

from __future__ import annotations

import os
import time
from typing import Any, Callable, Iterable, Iterator, Mapping, Optional, Sequence, Union

from robot_calib.io.bags import BagError, BagSet, normalize_topic

_NS = 1_000_000_000


def _bag_remaps(remaps: Union[None, Mapping[str, str], Iterable[str]],
                bag_topics: Iterable[str]) -> dict[str, str]:
    from robot_calib.replay.config import parse_remaps, ReplayError
    known = set(bag_topics)
    out = {}
    for src, dst in parse_remaps(remaps):
        if src not in known:
            raise ReplayError(f'--remap {src}:={dst}: {src} is not a topic in the bag(s) '
                              f'({", ".join(sorted(known)) or "none"})')
        out[src] = dst
    return out


def _choose(bagset: BagSet, rename: dict[str, str], wanted: Optional[set[str]],
            message_class: Any) -> tuple[list, dict[str, str]]:
    """Return the (stream, topic, message class) to publish and the topics skipped (reason)."""
    skipped: dict[str, str] = {}
    chosen = []
    for s in bagset.streams:
        topic = rename.get(s.topic, s.topic)
        if wanted is not None and topic not in wanted:
            continue
        cls = message_class(s.msgtype) if s.msgtype.count('/') == 2 else None
        if cls is None:
            from robot_calib.nodes.base import missing_type_hint
            hint = f' ({missing_type_hint(s.msgtype)})' if s.msgtype.startswith('tf2_msgs/') \
                else ''
            skipped[topic] = f'message type {s.msgtype} is not installed{hint}'
            continue
        chosen.append((s, topic, cls))
    if wanted is not None:
        missing = wanted - {t for _, t, _ in chosen} - set(skipped)
        if missing:
            raise BagError(f'topic(s) {sorted(missing)} not in the bag(s); bag topics: '
                           f'{", ".join(sorted(bagset.topics()))}')
    return chosen, skipped


class _Player:
    """The player node: one publisher per (topic, type), ``/clock``, paced publishing."""

    def __init__(self, node: Any, chosen: list, clock: bool, clock_period: float):
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from robot_calib.nodes.base import LATCHED_QOS, TF_STATIC_QOS
        reliable = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                              reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.VOLATILE)
        self.pubs = {}
        for s, topic, cls in chosen:
            key = (topic, s.msgtype)
            if key not in self.pubs:
                qos = TF_STATIC_QOS if topic == '/tf_static' else (
                    LATCHED_QOS if s.latched else reliable)
                self.pubs[key] = node.create_publisher(cls, topic, qos)
        self.by_stream = {id(s): (self.pubs[(topic, s.msgtype)], topic, s)
                          for s, topic, _ in chosen}
        self.clock_pub = None
        self.clock_period_ns = int(clock_period * _NS)
        self._next_clock: Optional[int] = None
        if clock:
            from builtin_interfaces.msg import Time
            from rosgraph_msgs.msg import Clock
            self.clock_pub = node.create_publisher(Clock, '/clock', 10)
            self._clock_msg, self._time_msg = Clock, Time
        self.counts: dict[str, int] = {}
        self.n = 0

    def wait_for_subscribers(self, timeout: float) -> None:
        """Wait up to ``timeout`` s until every publisher (``/clock`` too) has a subscriber."""
        deadline = time.monotonic() + max(timeout, 0.0)
        waited = list(self.pubs.values()) + ([self.clock_pub] if self.clock_pub else [])
        while time.monotonic() < deadline and any(
                p.get_subscription_count() == 0 for p in waited):
            time.sleep(0.01)

    def tick(self, time_ns: int) -> None:
        """Publish ``/clock`` at bag time ``time_ns`` when one is due (every clock period)."""
        if self.clock_pub is not None and (self._next_clock is None
                                           or time_ns >= self._next_clock):
            self.clock_pub.publish(self._clock_msg(clock=self._time_msg(
                sec=time_ns // _NS, nanosec=time_ns % _NS)))
            self._next_clock = time_ns + self.clock_period_ns

    def restart_clock(self) -> None:
        """Let ``/clock`` start over (a new loop begins at the bag's start again)."""
        self._next_clock = None

    def publish(self, stream: Any, time_ns: int, raw: bytes, skipped: dict[str, str]) -> None:
        """Publish ``/clock`` when due, then the message as ROS 2 CDR bytes."""
        self.tick(time_ns)
        pub, topic, s = self.by_stream[id(stream)]
        try:
            data = s.to_cdr(raw)
        except Exception:  # noqa: B902 - an undecodable ROS 1 message is skipped
            skipped[topic] = 'some messages could not be converted'
            return
        pub.publish(data)
        self.counts[topic] = self.counts.get(topic, 0) + 1
        self.n += 1


def _check_play_args(rate: float, start_offset: float, duration: Optional[float]) -> None:
    if not rate > 0:
        raise ValueError(f'bad rate {rate}: expected a positive factor')
    if not start_offset >= 0 or (duration is not None and not duration > 0):
        raise ValueError(f'bad time window: start offset {start_offset} s, duration '
                         f'{duration} s; expected a start >= 0 and a duration > 0')


def _paced(bagset: BagSet, streams: list, rate: float, start_offset: float,
           duration: Optional[float], span: list,
           tick: Optional[tuple[Callable[[int], None], float]] = None) -> Iterator[tuple]:
    """
    Yield ``(stream, time_ns, raw)`` at the recorded pace divided by ``rate``.

    ``span`` is filled with the bag times (ns) of the first and last message
    played; latched messages from before the start go out at once. While
    waiting for the next message, ``tick = (call, period s)`` is called with
    the bag time (ns) every ``period`` of bag time (``/clock`` keeps running).
    """
    wall0 = time.monotonic()
    t_lo = bagset.start_ns + int(round(start_offset * _NS))
    t_hi = None if duration is None else t_lo + int(round(duration * _NS))
    for stream, time_ns, raw in bagset.messages(streams):
        if time_ns < t_lo and not (stream.latched or stream.topic == '/tf_static'):
            continue
        if t_hi is not None and time_ns > t_hi:
            break
        if not span:
            span[:] = [max(time_ns, t_lo)] * 2
        previous, span[1] = span[1], max(time_ns, span[0])
        _wait_until(wall0 + (span[1] - span[0]) / _NS / rate, (previous, span[1]), span[0],
                    wall0, rate, tick)
        yield stream, time_ns, raw


def _wait_until(deadline: float, bag_ns: tuple[int, int], first_ns: int, wall0: float,
                rate: float, tick: Optional[tuple[Callable[[int], None], float]]) -> None:
    """
    Sleep until the monotonic time ``deadline``, ticking the bag clock meanwhile.

    ``bag_ns`` is the bag time (ns) of the message played last and of the next
    one; the ticks stay between the two.
    """
    while True:
        now = time.monotonic()
        if now >= deadline:
            return
        if tick is None:
            time.sleep(deadline - now)
            return
        call, period = tick
        time.sleep(min(deadline - now, period / rate))
        elapsed = first_ns + int((time.monotonic() - wall0) * rate * _NS)
        call(min(max(bag_ns[0], elapsed), bag_ns[1]))


def play(bags: Union[str, os.PathLike, Sequence[Union[str, os.PathLike]]], rate: float = 1.0,
         remaps: Union[None, Mapping[str, str], Iterable[str]] = None,
         topics: Optional[Iterable[str]] = None, clock: bool = True, delay: float = 0.5,
         clock_period: float = 0.01, wait_for_subscribers: float = 0.0,
         node_name: str = 'robot_calib_player', start_offset: float = 0.0,
         duration: Optional[float] = None, loops: int = 1) -> dict[str, Any]:
    """
    Publish the messages of ``bags`` on their topics at ``rate`` times the recorded speed.

    :param bags: bag paths (ROS 2 folders or ROS 1 ``.bag`` files).
    :param rate: playback speed factor (> 0; 2.0 plays twice as fast).
    :param remaps: ``FROM:=TO`` rules renaming bag topics.
    :param topics: publish only these bag topics (after remapping); None: all.
    :param clock: publish ``/clock`` with the bag time.
    :param delay: seconds to wait after creating the publishers (discovery), s.
    :param clock_period: publish ``/clock`` at most this often in bag time, s.
    :param wait_for_subscribers: wait up to this long (s) for every publisher
        (``/clock`` included) to have a subscriber before playing.
    :param node_name: name of the player node.
    :param start_offset: skip the first ``start_offset`` seconds of the recording (s).
    :param duration: play at most this many seconds after the start offset (s).
    :param loops: play the recording this many times (0: until interrupted); the bag
        time, and so ``/clock``, starts over with each loop.
    :return: ``{'messages', 'topics': {topic: count}, 'skipped': {topic: reason},
        'wall_seconds', 'bag_seconds', 'corrupt_chunks': [...]}`` (the mcap chunks
        skipped as corrupt, see :attr:`robot_calib.io.bags.BagSet.corrupt_chunks`).
    """
    _check_play_args(rate, start_offset, duration)
    if loops < 0:
        raise ValueError(f'bad loops {loops}: expected 0 (forever) or a count')
    bag_list = [bags] if isinstance(bags, (str, os.PathLike)) else list(bags)
    import rclpy
    from robot_calib.nodes.base import message_class
    with BagSet(bag_list) as bagset:
        rename = _bag_remaps(remaps, bagset.topics())
        wanted = None if topics is None else {normalize_topic(t) for t in topics}
        chosen, skipped = _choose(bagset, rename, wanted, message_class)
        own_context = not rclpy.ok()
        if own_context:
            rclpy.init(args=[])   # not sys.argv: its --remap are ours, not rcl's
        node = player = None
        span: list[int] = []
        wall0 = time.monotonic()
        try:
            node = rclpy.create_node(node_name)
            player = _Player(node, chosen, clock, clock_period)
            player.wait_for_subscribers(wait_for_subscribers)
            if delay > 0:
                time.sleep(delay)
            wall0 = time.monotonic()
            tick = (player.tick, clock_period) if clock else None
            loop = 0
            while loops <= 0 or loop < loops:
                loop += 1
                span.clear()
                player.restart_clock()
                for stream, time_ns, raw in _paced(bagset, [s for s, _, _ in chosen], rate,
                                                   start_offset, duration, span, tick):
                    player.publish(stream, time_ns, raw, skipped)
        finally:
            if node is not None:
                node.destroy_node()
            if own_context:
                rclpy.try_shutdown()
    return {'messages': player.n if player else 0, 'topics': player.counts if player else {},
            'skipped': skipped, 'wall_seconds': time.monotonic() - wall0,
            'bag_seconds': (span[1] - span[0]) / _NS if span else 0.0,
            'corrupt_chunks': bagset.corrupt_chunks}
