"""The raw messages of one bag topic, in blocks: each message's CDR bytes and its bag (receive) time
[ns], in the order ``rosbags``' reader gives them (by receive time, ties in storage order).

``rosbags`` opens the bag, parses its metadata, indexes and connections, reads and decompresses (and
checksums) MCAP chunks and queries the sqlite3 database. Two of its per-message layers are skipped
where the result is the same:

* **MCAP** (chunked): the messages of a chunk are found through the chunk's message index records (log
  time and offset per message, read with numpy), each record checked against its index entry (opcode,
  channel, log time, length) before its bytes are used; a chunk whose records do not match goes through
  rosbags' own chunk reader (``msgsrc``). Chunks are merged by log time as rosbags merges them.
* **sqlite3** (without per-message compression): each storage file's rows are read from the ``messages``
  table on the database connection rosbags opened (apsw; ``SELECT timestamp, data ... WHERE topic_id IN (...)
  ORDER BY timestamp``: rosbags' own query without its join to ``topics``, which only checks that the
  topic exists; both scan the ``timestamp`` index, so ties come in the same storage order), fetched
  :data:`SQLITE_FETCH` rows at a time and joined while they are in the cache, without rosbags'
  per-message generator, connection remapping and merge layers.

Anything else (per-message compression, unchunked MCAP files, several bags) is read through
``AnyReader.messages`` itself.
"""

from __future__ import annotations

import gc
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from itertools import islice
from operator import itemgetter
from typing import Any

import numpy as np

from reflexarm.logs._cdr import RawBlock

__all__ = ["BLOCK", "ChunkError", "raw_blocks"]

#: Messages per block: bounds the memory of the raw bytes held at once.
BLOCK = 1 << 16
#: Rows fetched from sqlite3 at once (their bytes joined while still in the cache: with 8192 rows of a 7-joint
#: JointState, 2.9 MB, the rows read 1.25x faster than fetched BLOCK at a time).
SQLITE_FETCH = 1 << 13
_INDEX = np.dtype([("time", "<u8"), ("offset", "<u8")])


def raw_blocks(reader: Any, topic: str, *, direct: bool = True) -> Iterator[RawBlock]:
    """The raw messages of ``topic`` in blocks of about :data:`BLOCK` messages; ``direct=False`` takes
    every message from ``AnyReader.messages`` (the reference)."""
    storages = _storages(reader) if direct else None
    if storages is None:
        yield from _blocks(reader.messages(connections=[c for c in reader.connections if c.topic == topic]))
        return
    from rosbags.rosbag2.storage_mcap import McapReader
    from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

    for storage in storages:
        conns = [c for c in storage.connections if c.topic == topic]
        if not conns:
            continue
        chunks = _mcap_chunks(storage, conns) if isinstance(storage, McapReader) else None
        if chunks is not None:
            yield from _mcap_blocks(storage, conns, chunks)
        elif isinstance(storage, Sqlite3Reader):
            yield from _sqlite_blocks(storage, conns)
        else:
            yield from _blocks(storage.messages(conns))


def _sqlite_blocks(storage: Any, conns: list[Any]) -> Iterator[RawBlock]:
    """The rows of rosbags' message query (``Sqlite3Reader.messages`` without start / stop) in blocks of
    :data:`BLOCK`, read from the database connection rosbags opened, :data:`SQLITE_FETCH` rows at a time."""
    ids = tuple(sorted({c.id for c in conns}))
    query = f"SELECT timestamp,data FROM messages WHERE topic_id IN ({','.join('?' for _ in ids)}) ORDER BY timestamp"
    rows_of = iter(storage.dbconn.execute(query, ids))  # an apsw cursor: no fetchmany, islice takes its rows
    while True:
        parts: list[bytes] = []
        stamps: list[np.ndarray] = []
        sizes: list[np.ndarray] = []
        count = 0
        with _no_gc():
            while count < BLOCK:
                rows = list(islice(rows_of, min(SQLITE_FETCH, BLOCK - count)))
                if not rows:
                    break
                received, raws = zip(*rows, strict=True)
                stamps.append(np.fromiter(received, dtype=np.int64, count=len(rows)))
                sizes.append(np.fromiter(map(len, raws), dtype=np.int64, count=len(rows)))
                parts.append(b"".join(raws))
                count += len(rows)
                del rows, received, raws
        if not count:
            return
        size = np.concatenate(sizes)
        data = np.frombuffer(parts[0] if len(parts) == 1 else b"".join(parts), dtype=np.uint8)
        yield RawBlock(data, np.cumsum(size) - size, size, np.concatenate(stamps))


def _blocks(messages: Iterable[tuple[Any, int, Any]]) -> Iterator[RawBlock]:
    it = iter(messages)
    while True:
        with _no_gc():
            block = list(islice(it, BLOCK))
        if not block:
            return
        raws = list(map(itemgetter(2), block))
        received = np.fromiter(map(itemgetter(1), block), dtype=np.int64, count=len(block))
        size = np.fromiter(map(len, raws), dtype=np.int64, count=len(raws))
        data = np.frombuffer(b"".join(raws), dtype=np.uint8)
        yield RawBlock(data, np.cumsum(size) - size, size, received)


@contextmanager
def _no_gc() -> Iterator[None]:
    """The cyclic garbage collector paused while a block of rows is built: each row is a new tuple, and
    the collector's passes over them cost ~40 % of reading (none of them can be in a cycle)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


class ChunkError(Exception):
    """An MCAP chunk (at byte ``offset``, log times ``start``..``end`` [ns]) that cannot be read."""

    def __init__(self, offset: int, start: int, end: int, cause: Exception) -> None:
        super().__init__(f"{type(cause).__name__}: {cause}")
        self.offset, self.start, self.end = offset, start, end


def _storages(reader: Any) -> list[Any] | None:
    """The storage files of a single rosbag2 bag read as the bag reader reads them, else None."""
    from rosbags.rosbag2 import Reader
    from rosbags.rosbag2.reader import DirectoryReader
    from rosbags.rosbag2.storage_mcap import McapReader
    from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

    if len(reader.readers) != 1 or not isinstance(reader.readers[0], Reader):
        return None
    storage = reader.readers[0].storage
    if isinstance(storage, DirectoryReader):
        if storage.metadata.compression_mode == "message":
            return None
        storages = list(storage.storages)
    else:
        storages = [storage]
    return storages if all(isinstance(s, McapReader | Sqlite3Reader) for s in storages) else None


def _mcap_chunks(storage: Any, conns: list[Any]) -> list[Any] | None:
    """The chunks holding ``conns`` in file order (rosbags' order for equal log times), None if unchunked."""
    if not storage.chunks:
        return None
    ids = {c.id for c in conns}
    return sorted((x for x in storage.chunks if any(x.channel_count.get(i, 0) for i in ids)),
                  key=lambda x: x.chunk_start_offset)  # fmt: skip


def _mcap_blocks(storage: Any, conns: list[Any], chunks: list[Any]) -> Iterator[RawBlock]:
    """The chunks' messages merged by log time as rosbags' ``heapq.merge`` does (ties: the earlier chunk
    in the file first): a message is given out once no later chunk can start before it."""
    later = np.minimum.accumulate(np.array([c.message_start_time for c in chunks], dtype=np.uint64)[::-1])[::-1]
    pending: list[RawBlock] = []
    for i, chunk in enumerate(chunks):
        try:
            pending.append(_chunk_messages(storage, conns, chunk))
        except Exception as e:  # rosbags' decompression and checksum errors, records beyond the chunk
            raise ChunkError(chunk.chunk_start_offset, chunk.message_start_time, chunk.message_end_time, e) from e
        if sum(p.size.size for p in pending) < BLOCK and i + 1 < len(chunks):
            continue
        block = _join(pending)
        order = np.argsort(block.received, kind="stable")
        ready = order if i + 1 == len(chunks) else order[block.received[order] <= int(later[i + 1])]
        rest = np.setdiff1d(order, ready, assume_unique=True)
        rest = rest[np.argsort(block.received[rest], kind="stable")] if rest.size else rest
        yield RawBlock(block.data, block.start[ready], block.size[ready], block.received[ready])
        pending = [_take(block, rest)] if rest.size else []


def _take(block: RawBlock, idx: np.ndarray) -> RawBlock:
    """Messages ``idx`` of ``block`` with their bytes copied out (the rest of the buffer released)."""
    starts, sizes = block.start[idx].tolist(), block.size[idx].tolist()
    data = np.concatenate([block.data[s : s + n] for s, n in zip(starts, sizes, strict=True)])
    size = block.size[idx]
    return RawBlock(data, np.cumsum(size) - size, size, block.received[idx])


def _join(parts: list[RawBlock]) -> RawBlock:
    shift = np.cumsum([0] + [p.data.size for p in parts[:-1]])
    return RawBlock(
        np.concatenate([p.data for p in parts]),
        np.concatenate([p.start + s for p, s in zip(parts, shift, strict=True)]),
        np.concatenate([p.size for p in parts]),
        np.concatenate([p.received for p in parts]),
    )


def _read_chunk(storage: Any, chunk: Any) -> bytes:
    from rosbags.rosbag2.storage_mcap import decompress, deserialize_uint32, read_exact

    bio = storage.bio
    bio.seek(chunk.chunk_start_offset + 9 + 24)
    (crc,) = deserialize_uint32(read_exact(bio, 4))
    bio.seek(chunk.chunk_start_offset + 9 + 40 + len(chunk.compression))
    return bytes(decompress(read_exact(bio, chunk.compressed_size), chunk.compression, chunk.uncompressed_size, crc))


def _index(storage: Any, chunk: Any, ids: set[int]) -> np.ndarray | None:
    """The chunk's message index entries (log time, offset) of channels ``ids``, in record order."""
    from rosbags.rosbag2.storage_mcap import read_exact

    parts = []
    for cid in ids:
        if not chunk.channel_count.get(cid, 0):
            continue
        storage.bio.seek(chunk.message_index_offsets[cid])
        head = read_exact(storage.bio, 1 + 8 + 2 + 4)
        size = int.from_bytes(head[11:15], "little")
        if head[0] != 0x07 or int.from_bytes(head[9:11], "little") != cid or size % 16:
            return None
        parts.append(np.frombuffer(read_exact(storage.bio, size), dtype=_INDEX))
    entries = np.concatenate(parts) if parts else np.zeros(0, _INDEX)
    return entries[np.argsort(entries["offset"], kind="stable")]


def _chunk_messages(storage: Any, conns: list[Any], chunk: Any) -> RawBlock:
    """The chunk's messages of ``conns`` in log time order (ties in record order, as rosbags' ``msgsrc``)."""
    ids = {c.id for c in conns}
    data = _read_chunk(storage, chunk)
    entries = _index(storage, chunk, ids)
    if entries is not None and entries.size:
        u8 = np.frombuffer(data, dtype=np.uint8)
        off = entries["offset"].astype(np.int64)
        if off.max() + 31 <= u8.size:
            head = u8[off[:, None] + np.arange(31)]  # opcode, length, channel, sequence, log time, publish time
            length = head[:, 1:9].copy().view("<u8")[:, 0].astype(np.int64)
            channel = head[:, 9:11].copy().view("<u2")[:, 0]
            log_time = head[:, 15:23].copy().view("<u8")[:, 0]
            ok = (head[:, 0] == 0x05) & (length >= 22) & (off + 9 + length <= u8.size)
            ok &= np.isin(channel, list(ids)) & (log_time == entries["time"])
            if ok.all():
                order = np.argsort(log_time, kind="stable")
                return RawBlock(u8, (off + 31)[order], (length - 22)[order], log_time[order].astype(np.int64))
    return _chunk_by_rosbags(storage, conns, chunk)


def _chunk_by_rosbags(storage: Any, conns: list[Any], chunk: Any) -> RawBlock:
    from rosbags.rosbag2.storage_mcap import msgsrc

    cmap = {c.id: c for c in conns}
    msgs = msgsrc(chunk, cmap, chunk.message_start_time, chunk.message_end_time + 1, storage.bio)
    blocks = list(_blocks((m.connection, m.timestamp, m.data) for m in msgs if m.offset))
    if not blocks:
        empty = np.zeros(0, dtype=np.int64)
        return RawBlock(np.zeros(0, dtype=np.uint8), empty, empty, empty)
    return _join(blocks)
