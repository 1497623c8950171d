# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
mcap details below rosbags: a fast chunk reader, corrupt chunks, chunk CRCs, direct appends.

rosbags parses mcap files and writes them; :mod:`robot_calib.io.bags` (reading)
and :mod:`robot_calib.io.bag_writer` use it and add here what replay needs from
the format itself:

- :func:`messages` reads the records of each chunk with ``struct`` instead of
  rosbags' per-field loop, and skips a corrupt chunk whole (reported, never
  partly used) instead of ending the run;
- :func:`write_chunk_crcs` makes rosbags' writer store every chunk's CRC-32
  (it stores 0, "not computed"), so that readers can tell a corrupt chunk;
- :func:`fast_storage` and :data:`MESSAGE_HEADER` let the bag writer append
  message records directly, byte for byte as rosbags would, and
  :func:`fast_close_chunk` closes its chunks with ``struct`` (same bytes).

Record layouts: the mcap specification (https://mcap.dev/spec), op codes
0x05 (Message), 0x06 (Chunk), 0x07 (Message Index) and 0x08 (Chunk Index).
"""

from __future__ import annotations

from collections import defaultdict
import heapq
from io import BytesIO
from itertools import chain
from operator import itemgetter
from pathlib import Path
import struct
from typing import Any, Iterable, Iterator, Optional
import zlib

MESSAGE_HEADER = struct.Struct('<BQHIQQ')
"""Op code, record length, channel id, sequence, log time, publish time of a Message record."""
CHUNK_CRC_OFFSET = 1 + 8 + 8 + 8 + 8
"""Bytes from the start of a Chunk record to its uncompressed_crc (op, length, 3 fields)."""
_CHUNK_DATA_OFFSET = 1 + 8 + 8 + 8 + 8 + 4 + 4
"""Bytes from the start of a Chunk record to its compression string (then its data)."""
_MESSAGE = struct.Struct('<HIQ')  # channel id, sequence, log time
_U32 = struct.Struct('<I')
_U64 = struct.Struct('<Q')


class BareMcap:
    """A single ROS 2 ``.mcap`` file without metadata.yaml, read through rosbags' McapReader."""

    def __init__(self, path: Path):
        from rosbags.rosbag2.storage_mcap import McapReader
        self.mcap = McapReader(path)

    def open(self) -> None:  # noqa: A003 - the reader interface rosbags defines
        self.mcap.open()

    def close(self) -> None:
        self.mcap.close()

    @property
    def connections(self) -> list:
        return self.mcap.connections

    @property
    def message_count(self) -> int:
        return self.mcap.metadata.message_count

    @property
    def start_time(self) -> int:
        return self.mcap.metadata.start_time

    @property
    def end_time(self) -> int:
        return self.mcap.metadata.end_time

    def messages(self, connections: Iterable[Any] = ()) -> Iterator[tuple[Any, int, bytes]]:
        return self.mcap.messages(list(connections) or self.mcap.connections)


def messages(reader: Any, conns: list, streams: dict, corrupt: Optional[list] = None
             ) -> Optional[Iterator[tuple[Any, int, bytes]]]:
    """
    Return a fast message iterator over an indexed ROS 2 mcap bag, or None to use rosbags.

    rosbags parses the file and its chunk index; this only replaces its per-record
    loop (BytesIO reads per field) with ``struct.unpack_from`` over each
    decompressed chunk, in the same order rosbags yields: files one after the
    other, chunks by start time, messages by log time (stable); it yields
    ``(streams[id(connection)], time_ns, raw)``; chunks that overlap in time
    are merged by log time as rosbags merges them. Bags it does not cover
    (per-message compression, unindexed files) return None.

    A chunk that fails its CRC-32 (when the writer stored one), does not
    decompress or whose records do not parse is skipped whole, never partly
    used: it is described in ``corrupt`` (file, byte offset, time span, the
    messages lost per topic, why) and reading goes on with the next chunk.
    Without ``corrupt`` the error is raised.
    """
    from rosbags.rosbag2.storage_mcap import McapReader
    if isinstance(reader, BareMcap):
        subs = [reader.mcap]
    else:
        storage = getattr(reader, 'storage', None)
        subs = getattr(storage, 'storages', None)
        if not subs or getattr(storage.metadata, 'compression_mode', None) == 'message':
            return None
    plans = []
    for sub in subs:
        if not isinstance(sub, McapReader) or not sub.chunks or sub.bio is None:
            return None
        connmap = {}
        for x in sub.connections:
            for y in conns:
                if y.topic == x.topic and y.msgtype == x.msgtype and y.ext == x.ext:
                    connmap[x.id] = streams[id(y)]
                    break
        chunks = sorted((c for c in sub.chunks
                         if any(c.channel_count.get(cid, 0) for cid in connmap)),
                        key=lambda c: c.message_start_time)
        overlap = any(b.message_start_time < a.message_end_time
                      for a, b in zip(chunks, chunks[1:]))
        plans.append((sub, connmap, chunks, overlap))

    def generate() -> Iterator[tuple[Any, int, bytes]]:
        for sub, connmap, chunks, overlap in plans:
            if overlap:
                yield from _merged(sub, chunks, connmap, corrupt)
                continue
            for chunk in chunks:
                try:
                    out = _chunk_messages(sub.bio, chunk, connmap)
                except Exception as exc:  # noqa: B902 - any failure: the chunk is corrupt
                    if corrupt is None:
                        raise
                    corrupt.append(_corrupt_chunk(sub, chunk, connmap, exc))
                    continue
                yield from out
    return generate()


def _merged(sub: Any, chunks: list, connmap: dict, corrupt: Optional[list]
            ) -> Iterator[tuple[Any, int, bytes]]:
    """
    Yield the messages of chunks that overlap in time, merged by log time as rosbags does.

    Each chunk is decompressed only once the merge reaches its start time, and
    ties go to the chunk earlier in the file (rosbags' order: log time, then
    chunk offset, then the order within the chunk). A corrupt chunk is skipped
    whole and described in ``corrupt``, as in the ordered case.
    """
    def source(chunk: Any) -> Iterator[tuple[int, int, int, Any]]:
        offset = chunk.chunk_start_offset
        yield chunk.message_start_time, offset, -1, None  # opens the chunk no earlier
        try:
            out = _chunk_messages(sub.bio, chunk, connmap)
        except Exception as exc:  # noqa: B902 - any failure: the chunk is corrupt
            if corrupt is None:
                raise
            corrupt.append(_corrupt_chunk(sub, chunk, connmap, exc))
            return
        for i, message in enumerate(out):
            yield message[1], offset, i, message

    for _, _, _, message in heapq.merge(*map(source, chunks)):
        if message is not None:
            yield message


def _chunk_messages(bio: Any, chunk: Any, connmap: dict) -> list[tuple[Any, int, bytes]]:
    """Return the wanted messages of one chunk in log-time order; raise when it is corrupt."""
    from rosbags.rosbag2.storage_mcap import decompress
    bio.seek(chunk.chunk_start_offset + CHUNK_CRC_OFFSET)
    crc = _U32.unpack(bio.read(4))[0]
    bio.seek(chunk.chunk_start_offset + _CHUNK_DATA_OFFSET + len(chunk.compression) + 8)
    data = bio.read(chunk.compressed_size)
    if len(data) != chunk.compressed_size:
        raise ValueError('mcap chunk is cut short')
    buf = bytes(decompress(data, chunk.compression, chunk.uncompressed_size, crc))
    unpack_msg, unpack_u64 = _MESSAGE.unpack_from, _U64.unpack_from
    out = []
    pos, end = 0, len(buf)
    while pos < end:
        length = unpack_u64(buf, pos + 1)[0]
        if buf[pos] == 0x05:
            cid, _, log_time = unpack_msg(buf, pos + 9)
            stream = connmap.get(cid)
            if stream is not None:
                out.append((stream, log_time, buf[pos + 31:pos + 9 + length]))
        pos += 9 + length
    if pos != end:
        raise ValueError('mcap chunk records overrun the chunk')
    times = [m[1] for m in out]
    if times != sorted(times):
        out.sort(key=itemgetter(1))
    return out


def _corrupt_chunk(sub: Any, chunk: Any, connmap: dict, exc: BaseException) -> dict:
    """Describe a skipped chunk: file, byte offset, time span (s), lost messages, reason."""
    lost: dict[str, int] = {}
    for cid, n in chunk.channel_count.items():
        stream = connmap.get(cid)
        if stream is not None:
            lost[stream.topic] = lost.get(stream.topic, 0) + n
    return {'file': str(sub.path), 'offset': chunk.chunk_start_offset,
            'start_time': chunk.message_start_time * 1e-9,
            'end_time': chunk.message_end_time * 1e-9,
            'messages': lost, 'reason': ' '.join(str(exc).split()) or type(exc).__name__}


def append_message(st: Any, cid: int, ts: int, data: bytes) -> None:
    """
    Append a Message record to the open chunk of rosbags' McapWriter ``st``, as it would.

    Channel ``cid``, log and publish time ``ts`` (ns), sequence 0; the chunk's
    time span and message index are kept, and the chunk is closed once past
    1 MiB. The file-wide statistics are the caller's.
    """
    chunk = st.chunk
    if ts < chunk.message_start_time:
        chunk.message_start_time = ts
    if ts > chunk.message_end_time:
        chunk.message_end_time = ts
    bio = chunk.bio
    pos = bio.tell()
    chunk.msgs[cid].append((ts, pos))
    bio.write(MESSAGE_HEADER.pack(0x05, 22 + len(data), cid, 0, ts, ts))
    bio.write(data)
    if pos + 31 + len(data) > 2**20:
        st.close_chunk()


def fast_storage(writer: Any) -> Any:
    """Return rosbags' McapWriter of an open Writer when records can be appended directly."""
    from rosbags.rosbag2 import CompressionMode
    from rosbags.rosbag2.storage_mcap import McapWriter
    st = getattr(writer, 'storage', None)
    if type(st) is not McapWriter or writer.compression_mode == CompressionMode.MESSAGE:
        return None
    needed = ('chunk', 'channel_stats', 'message_start_time', 'message_end_time', 'close_chunk')
    if not all(hasattr(st, n) for n in needed) or not all(
            hasattr(writer, n) for n in ('counts', 'min_timestamp', 'max_timestamp')):
        return None
    return st


def write_chunk_crcs(writer: Any) -> None:
    """
    Make an open rosbags mcap writer store each chunk's CRC-32 (rosbags stores 0, "none").

    Readers (this module, rosbag2, the mcap tools) then detect a corrupt chunk
    instead of decoding garbage. The CRC of the uncompressed records is taken
    before the chunk is written and patched into its record afterwards.
    """
    from rosbags.rosbag2.storage_mcap import McapWriter
    st = getattr(writer, 'storage', None)
    if type(st) is not McapWriter or not hasattr(st, 'chunk') or not hasattr(st, 'bio'):
        return
    close_chunk = st.close_chunk

    def close_chunk_with_crc() -> None:
        crc = zlib.crc32(st.chunk.bio.getvalue())
        start = st.bio.tell()
        close_chunk()
        end = st.bio.tell()
        st.bio.seek(start + CHUNK_CRC_OFFSET)
        st.bio.write(_U32.pack(crc))
        st.bio.seek(end)

    st.close_chunk = close_chunk_with_crc


_CHUNK_HEAD = struct.Struct('<BQQQQII')
"""Op 0x06, record length, message start and end time, uncompressed size, CRC, string length."""
_INDEX_HEAD = struct.Struct('<BQHI')
"""Op 0x07, record length, channel id, length of the (log time, offset) pairs in bytes."""


def fast_close_chunk(st: Any) -> None:
    """
    Make rosbags' McapWriter ``st`` close chunks with ``struct`` (same bytes, CRC included).

    rosbags writes each chunk's message index field by field (two BytesIO writes a
    message); this packs each record at once: the Chunk (0x06) with the CRC-32
    :func:`write_chunk_crcs` stores, a Message Index (0x07) per channel, and the
    Chunk Index (0x08) body kept for the summary, laid out as the specification
    and rosbags lay them out. Times outside uint64 take the former path.
    """
    from rosbags.rosbag2.storage_mcap import PendingChunk
    former = st.close_chunk
    u64 = _U64.pack

    def close_chunk() -> None:
        chunk = st.chunk
        start, end = chunk.message_start_time, chunk.message_end_time
        if not (0 <= start and end < 2**64):
            former()
            return
        raw = chunk.bio.getvalue()
        compressed = st.compressor(raw)
        comp = st.compression.encode()
        bio = st.bio
        chunk_start = bio.tell()
        bio.write(_CHUNK_HEAD.pack(0x06, 40 + len(comp) + len(compressed), start, end,
                                   len(raw), zlib.crc32(raw), len(comp)))
        bio.write(comp)
        bio.write(u64(len(compressed)))
        bio.write(compressed)
        chunk_end = bio.tell()
        offsets = []
        for cid, msgs in chunk.msgs.items():
            offsets.append(struct.pack('<HQ', cid, bio.tell()))
            bio.write(_INDEX_HEAD.pack(0x07, 6 + 16 * len(msgs), cid, 16 * len(msgs)))
            bio.write(struct.pack(f'<{2 * len(msgs)}Q', *chain.from_iterable(msgs)))
        rec = BytesIO()
        rec.write(struct.pack('<QQQQI', start, end, chunk_start, chunk_end - chunk_start,
                              10 * len(offsets)))
        rec.write(b''.join(offsets))
        rec.write(u64(bio.tell() - chunk_end))
        rec.write(_U32.pack(len(comp)))
        rec.write(comp)
        rec.write(struct.pack('<QQ', len(compressed), len(raw)))
        st.chunks.append(rec)
        st.chunk = PendingChunk(2**63 - 1, 0, BytesIO(), defaultdict(list))

    st.close_chunk = close_chunk
