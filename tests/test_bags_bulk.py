"""Bags decoded in bulk (issue 19 item 3) against the per-message reference (rosbags deserializing each
message), bit for bit; corrupt messages and clocks that jump back are DataErrors naming topic, message
and stamp (issue 20 items 3 and 11).

The bags are written with rosbags' own writer and serializer (little- and big-endian CDR), never by
reflexarm: a 7-joint arm topic whose joint order changes mid-bag and between messages, with a gripper's
own messages on it, a gripper topic, and a wrist WrenchStamped topic with two frames.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from reflexarm.cli import main
from reflexarm.errors import DataError
from reflexarm.logs import _cdr, load_log
from reflexarm.logs.bags import _open, _read_topic, read_bag

STORE = get_typestore(Stores.ROS2_HUMBLE)
T = STORE.types
JS, WS = "sensor_msgs/msg/JointState", "geometry_msgs/msg/WrenchStamped"
ARM = [f"panda_joint{k}" for k in range(1, 8)]
EPOCH_NS = 1_795_435_200_000_000_000
PERIOD_NS = 1_000_000
#: values whose bits a decoder could change: -0.0, NaN, inf, a subnormal, the largest double
SPECIAL = np.array([-0.0, np.nan, np.inf, -np.inf, 5e-324, 1.7976931348623157e308, 1e-300])


def _header(stamp: int, frame: str = "") -> object:
    return T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id=frame
    )


def _joint_state(stamp: int, names: list[str], pos, vel, eff, frame: str = "") -> object:
    f8 = [np.ascontiguousarray(a, dtype=np.float64) for a in (pos, vel, eff)]
    return T[JS](header=_header(stamp, frame), name=list(names), position=f8[0], velocity=f8[1], effort=f8[2])


def _wrench(stamp: int, w: np.ndarray, frame: str) -> object:
    V = T["geometry_msgs/msg/Vector3"]
    return T[WS](
        header=_header(stamp, frame),
        wrench=T["geometry_msgs/msg/Wrench"](force=V(x=w[0], y=w[1], z=w[2]), torque=V(x=w[3], y=w[4], z=w[5])),
    )


def _ser(msg: object, msgtype: str, k: int, endian: str) -> bytes:
    little = endian == "little" or (endian == "mixed" and k % 3 != 0)
    return bytes(STORE.serialize_cdr(msg, msgtype, little_endian=little))


def write_arm_bag(
    path: Path, storage: str, *, n: int = 300, endian: str = "little", seed: int = 0, raw=None, compression=None
) -> dict:
    """The bag, and the truth: the arm's q, dq, tau (n, 7) in ARM order and its header stamps.

    ``raw(k, data) -> data`` may replace the serialized bytes of arm message k (corruption tests)."""
    rng = np.random.default_rng(seed)
    q, dq, tau = rng.normal(size=(3, n, 7))
    q[5, :] = SPECIAL  # every special value through both paths (bits compared)
    stamps = EPOCH_NS + np.arange(n) * PERIOD_NS + rng.integers(0, 20_000, n)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    w = Writer(path, version=9, storage_plugin=plugin)
    if compression is not None:
        w.set_compression(compression, CompressionFormat.ZSTD)
    with w:
        arm = w.add_connection("/joint_states", JS, typestore=STORE)
        grip = w.add_connection("/gripper/joint_states", JS, typestore=STORE)
        ft = w.add_connection("/ft", WS, typestore=STORE)
        for k in range(n):
            s = int(stamps[k])
            order = np.arange(7) if k < n // 2 else np.arange(7)[::-1]  # the order changes mid-bag ...
            if k % 13 == 5:
                order = rng.permutation(7)  # ... and now and then from one message to the next
            if k % 10 == 0:  # a gripper's own message on the arm topic: 2 joints, no velocity or effort
                g = _joint_state(s, ["finger_joint1", "finger_joint2"], [0.04, np.nan], [], [])
                w.write(arm, s + 100_000, _ser(g, JS, k, endian))
            frame = "base" if k % 50 == 7 else ""
            msg = _joint_state(s, [ARM[j] for j in order], q[k, order], dq[k, order], tau[k, order], frame)
            data = _ser(msg, JS, k, endian)
            w.write(arm, s + 300_000, raw(k, data) if raw is not None else data)
            if k % 4 == 0:
                g = _joint_state(s, ["finger_joint1", "finger_joint2"], [0.04, 0.04], [0.0, 0.0], [1.0, 2.0])
                w.write(grip, s + 200_000, _ser(g, JS, k, endian))
            wrench = np.r_[rng.normal(size=6)]
            w.write(ft, s + 250_000, _ser(_wrench(s, wrench, "ft_sensor" if k < n - 20 else "tool0"), WS, k, endian))
    return {"q": q, "dq": dq, "tau": tau, "stamps": stamps}


def _topic(p: Path, topic: str, kind: _cdr.Kind, bulk: bool):
    with _open(p) as reader:
        return _read_topic(reader, topic, kind, p.name, bulk)


def _assert_same_bits(a: np.ndarray, b: np.ndarray, what: str) -> None:
    assert a.shape == b.shape and a.dtype == b.dtype, (what, a.shape, b.shape, a.dtype, b.dtype)
    assert a.tobytes() == b.tobytes(), what  # bit for bit: NaN payloads, -0.0, subnormals


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
@pytest.mark.parametrize("endian", ["little", "big", "mixed"])
def test_bulk_decoding_equals_the_per_message_reference_bit_for_bit(tmp_path, storage, endian):
    p = tmp_path / "bag"
    truth = write_arm_bag(p, storage, endian=endian)
    for topic, kind in (("/joint_states", _cdr.JOINT_STATE), ("/gripper/joint_states", _cdr.JOINT_STATE),
                        ("/ft", _cdr.WRENCH)):  # fmt: skip
        bulk, ref = _topic(p, topic, kind, True), _topic(p, topic, kind, False)
        _assert_same_bits(bulk.received, ref.received, f"{topic} receive times")
        assert [b.key for b in bulk.batches] == [b.key for b in ref.batches], topic
        for b, r in zip(bulk.batches, ref.batches, strict=True):
            _assert_same_bits(b.msg_index, r.msg_index, f"{topic} {b.key} message indices")
            _assert_same_bits(b.stamp, r.stamp, f"{topic} {b.key} stamps")
            for x, y in zip(b.arrays, r.arrays, strict=True):
                _assert_same_bits(x, y, f"{topic} {b.key} values")
        # every message went through the bulk path (the layouts are few), none one by one
        assert (bulk.n_bulk, ref.n_bulk) == (bulk.received.size, 0), topic
    arrays, notes = read_bag(p, joint_names=tuple(ARM), n_joints=None, joint_topic="/joint_states", wrench_topic="/ft")
    ref_arrays, ref_notes = read_bag(
        p, joint_names=tuple(ARM), n_joints=None, joint_topic="/joint_states", wrench_topic="/ft", bulk=False
    )
    assert notes == ref_notes
    assert sorted(arrays) == sorted(ref_arrays) == ["dq", "q", "t", "tau", "wrench"]
    for k in arrays:
        _assert_same_bits(arrays[k], ref_arrays[k], k)
    # and both are the truth (mapped by name), the samples inside the wrench's span
    inside = slice(0, truth["q"].shape[0])
    for k in ("q", "dq", "tau"):
        _assert_same_bits(arrays[k], truth[k][inside], k)
    assert "the joint order changes between /joint_states messages; mapped by name per message" in "\n".join(notes)
    assert "frame 'ft_sensor', 'tool0'" in "\n".join(notes)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_layouts_beyond_the_template_limit_and_trailing_bytes_go_one_by_one_with_the_same_result(
    tmp_path, storage, monkeypatch
):
    """Messages with 1-3 trailing bytes (rosbags accepts them) and, with a template limit of 1, every
    layout after the first deserialized one by one: the result is still the reference's."""
    p = tmp_path / "bag"
    write_arm_bag(p, storage, raw=lambda k, data: data + b"\0" * (k % 4))
    monkeypatch.setattr(_cdr, "MAX_TEMPLATES", 1)
    bulk, ref = _topic(p, "/joint_states", _cdr.JOINT_STATE, True), _topic(p, "/joint_states", _cdr.JOINT_STATE, False)
    assert 0 < bulk.n_bulk < bulk.received.size  # some of each path
    for b, r in zip(bulk.batches, ref.batches, strict=True):
        assert b.key == r.key
        for x, y in zip((b.msg_index, b.stamp, *b.arrays), (r.msg_index, r.stamp, *r.arrays), strict=True):
            _assert_same_bits(x, y, str(b.key))


@pytest.mark.parametrize(
    "storage, compression",
    [("mcap", None), ("mcap", CompressionMode.STORAGE), ("mcap", CompressionMode.FILE),
     ("sqlite3", CompressionMode.MESSAGE), ("sqlite3", CompressionMode.FILE)],
)  # fmt: skip
def test_chunks_merged_and_compressed_bags_in_the_reference_order(tmp_path, storage, compression):
    """6000 samples: several MCAP chunks whose time ranges overlap (the wrench is written after the arm
    message it precedes in time), merged as rosbags merges them; compressed chunks, files and messages."""
    p = tmp_path / "bag"
    write_arm_bag(p, storage, n=6000, compression=compression)
    if storage == "mcap" and compression is not CompressionMode.FILE:
        from rosbags.highlevel import AnyReader

        with AnyReader([p]) as reader:
            chunks = reader.readers[0].storage.storages[0].chunks
            assert len(chunks) >= 3
            assert any(b.message_start_time < a.message_end_time for a, b in zip(chunks, chunks[1:], strict=False))
    for topic, kind in (("/joint_states", _cdr.JOINT_STATE), ("/ft", _cdr.WRENCH)):
        bulk, ref = _topic(p, topic, kind, True), _topic(p, topic, kind, False)
        _assert_same_bits(bulk.received, ref.received, topic)
        # (hundreds of random joint orders: past the template limit, the rarer ones go one by one)
        assert bulk.n_bulk > bulk.received.size // 2
        for b, r in zip(bulk.batches, ref.batches, strict=True):
            assert b.key == r.key
            for x, y in zip((b.msg_index, b.stamp, *b.arrays), (r.msg_index, r.stamp, *r.arrays), strict=True):
                _assert_same_bits(x, y, f"{topic} {b.key}")


def _zeroed(data: bytes) -> bytes:
    return bytes(len(data))


def _huge_name_count(data: bytes) -> bytes:
    out = bytearray(data)  # the name sequence's count: after stamp (8) and the empty frame id (4 + 1, padded to 4)
    out[4 + 16 : 4 + 20] = (10**9).to_bytes(4, "little" if data[1] else "big")
    return bytes(out)


def _a_wrench(data: bytes) -> bytes:
    return bytes(STORE.serialize_cdr(_wrench(EPOCH_NS, np.arange(6.0), "ft_sensor"), WS))


@pytest.mark.parametrize("bulk", [True, False])
@pytest.mark.parametrize(
    "corrupt, reason",
    [
        (_zeroed, "Invalid string length 0"),
        (_huge_name_count, "Invalid sequence length 1000000000"),
        (_a_wrench, ""),
        (lambda data: data[: len(data) // 2], ""),
    ],
    ids=["zeroed", "sequence length 1e9", "another type's payload", "truncated"],
)
def test_a_corrupt_message_is_a_data_error_naming_topic_message_and_stamp(tmp_path, corrupt, reason, bulk):
    p = tmp_path / "bag"
    bad = 123
    # a second corrupt message later (shorter: its size group is decoded first): the first one is named
    truth = write_arm_bag(p, "mcap", raw=lambda k, data: corrupt(data) if k == bad else data[:40] if k == 200 else data)
    index = bad + bad // 10 + 1  # the arm topic's message index: a gripper message before every 10th sample
    received = int(truth["stamps"][bad]) + 300_000
    stamp = f"{received // 10**9}.{received % 10**9:09d}"
    with pytest.raises(DataError) as info:
        read_bag(p, joint_names=tuple(ARM), n_joints=None, joint_topic="/joint_states", wrench_topic=None, bulk=bulk)
    text = str(info.value)
    assert text.startswith(f"bag: /joint_states message {index} (bag time {stamp} s) does not decode as {JS}: "), text
    assert reason in text
    assert (info.value.column, info.value.row, info.value.expected) == ("/joint_states", index, JS)


def test_a_corrupt_message_ends_every_command_reading_logs_with_exit_2(tmp_path, capsys, atlas):
    names = list(atlas.joint_names)
    p = tmp_path / "bag"
    n = 200
    rng = np.random.default_rng(1)
    with Writer(p, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/joint_states", JS, typestore=STORE)
        for k in range(n):
            s = EPOCH_NS + k * PERIOD_NS
            data = bytes(STORE.serialize_cdr(_joint_state(s, names, *rng.normal(size=(3, 7)) * 0.1), JS))
            w.write(c, s, _zeroed(data) if k == 77 else data)
    expected = f"bag: /joint_states message 77 (bag time {(EPOCH_NS + 77 * PERIOD_NS) // 10**9}.077000000 s) does not"
    out = tmp_path / "out"
    for args in (
        ["identify", "dynamics", "--log", str(p), "--quiet"],
        ["identify", "friction", "--run", f"1={p}", "--quiet"],
        ["tune-thresholds", str(p), "--no-figure"],
    ):
        assert main([*args, "--out", str(out)]) == 2, args
        err = capsys.readouterr().err
        assert expected in err and "Traceback" not in err, err
    assert not out.exists() or not any(out.iterdir())


def _jumped(n: int, at: int, back_ns: int) -> np.ndarray:
    s = EPOCH_NS + np.arange(n) * PERIOD_NS
    s[at:] -= back_ns
    return s


def _write_stamped(p: Path, stamps: np.ndarray, names: list[str], wrench_stamps: np.ndarray | None = None) -> None:
    rng = np.random.default_rng(2)
    with Writer(p, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/joint_states", JS, typestore=STORE)
        ft = w.add_connection("/ft", WS, typestore=STORE)
        for k, s in enumerate(stamps.tolist()):
            received = EPOCH_NS + k * PERIOD_NS + 300_000  # the recorder's clock runs on
            w.write(c, received, bytes(STORE.serialize_cdr(_joint_state(s, names, *rng.normal(size=(3, 7)) * 0.1), JS)))
            ws = stamps[k] if wrench_stamps is None else wrench_stamps[k]
            w.write(ft, received + 1, bytes(STORE.serialize_cdr(_wrench(int(ws), np.zeros(6), "ft"), WS)))


def test_a_header_clock_that_jumps_back_or_runs_backwards_is_refused(tmp_path):
    n = 400
    _write_stamped(tmp_path / "jump", _jumped(n, n // 2, 5 * 10**9), ARM)
    at = EPOCH_NS + (n // 2) * PERIOD_NS - 5 * 10**9
    before = EPOCH_NS + (n // 2 - 1) * PERIOD_NS
    with pytest.raises(DataError) as info:
        load_log(tmp_path / "jump", joint_names=ARM)
    assert str(info.value) == (
        f"jump: the /joint_states header stamps go back 4.999 s at message 200 (header stamp "
        f"{at // 10**9}.{at % 10**9:09d} s after {before // 10**9}.{before % 10**9:09d} s at message 199): more than "
        "10 sample periods (0.01 s), so not a late message but a clock that jumped back or runs backwards; the "
        "samples' order and times are unknown"
    )
    assert (info.value.column, info.value.row, info.value.value) == ("/joint_states", 200, at)
    _write_stamped(tmp_path / "backwards", EPOCH_NS - np.arange(n) * PERIOD_NS, ARM)
    with pytest.raises(DataError, match=r"backwards: the /joint_states header stamps go back 0\.011 s at message 11 "):
        load_log(tmp_path / "backwards", joint_names=ARM)
    # the wrench's own clock is checked as well
    _write_stamped(tmp_path / "wrench", _jumped(n, 0, 0), ARM, wrench_stamps=_jumped(n, 300, 2 * 10**9))
    with pytest.raises(DataError, match=r"wrench: the /ft header stamps go back 1\.\d+ s at message 300 "):
        load_log(tmp_path / "wrench", joint_names=ARM, wrench_topic="/ft")
    # a few messages late by less than 10 periods are still sorted by stamp (a recorder's reordering)
    late = _jumped(n, 0, 0)
    late[[100, 101, 102]] = late[[102, 100, 101]]
    _write_stamped(tmp_path / "late", late, ARM)
    log = load_log(tmp_path / "late", joint_names=ARM)
    assert "late: 3 /joint_states message(s) were recorded out of stamp order; sorted by stamp" in log.notes


def test_identify_dynamics_on_a_bag_whose_clock_jumps_back_writes_no_model(tmp_path, capsys, atlas):
    """Issue 20 item 3: a model file and exit 0 before; now exit 2 naming the message, nothing written."""
    n = 2000
    p = tmp_path / "jump"
    _write_stamped(p, _jumped(n, n // 2, 5 * 10**9), list(atlas.joint_names))
    out = tmp_path / "out"
    assert main(["identify", "dynamics", "--log", str(p), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "jump: the /joint_states header stamps go back 4.999 s at message 1000 " in err, err
    assert not list(out.glob("*.json")) if out.exists() else True
    assert "Traceback" not in err


def test_an_mcap_chunk_whose_index_disagrees_with_its_records_is_read_by_rosbags(tmp_path, monkeypatch):
    """The message index entries of the first chunk point one byte off: the records' checks fail, that
    chunk goes through rosbags' own chunk reader and the result is still the reference's."""
    from rosbags.highlevel import AnyReader

    from reflexarm.logs import _bag_messages

    p = tmp_path / "bag"
    write_arm_bag(p, "mcap", n=3000)
    (f,) = p.glob("*.mcap")
    with AnyReader([p]) as reader:
        chunk = reader.readers[0].storage.storages[0].chunks[0]
        arm = next(c.id for c in reader.connections if c.topic == "/joint_states")
    data = bytearray(f.read_bytes())
    at = chunk.message_index_offsets[arm] + 1 + 8 + 2 + 4  # the first (log time, offset) entry
    offset = int.from_bytes(data[at + 8 : at + 16], "little")
    data[at + 8 : at + 16] = (offset + 1).to_bytes(8, "little")
    f.write_bytes(bytes(data))
    by_rosbags = []
    original = _bag_messages._chunk_by_rosbags
    monkeypatch.setattr(_bag_messages, "_chunk_by_rosbags", lambda *a: by_rosbags.append(a[2]) or original(*a))
    bulk, ref = _topic(p, "/joint_states", _cdr.JOINT_STATE, True), _topic(p, "/joint_states", _cdr.JOINT_STATE, False)
    assert by_rosbags == [chunk]
    _assert_same_bits(bulk.received, ref.received, "receive times")
    for b, r in zip(bulk.batches, ref.batches, strict=True):
        assert b.key == r.key
        for x, y in zip((b.msg_index, b.stamp, *b.arrays), (r.msg_index, r.stamp, *r.arrays), strict=True):
            _assert_same_bits(x, y, str(b.key))


def test_a_bag_whose_own_joint_state_definition_differs_is_a_data_error(tmp_path):
    """The reader prefers the definitions stored in the bag: a 'sensor_msgs/msg/JointState' without
    effort deserializes, but is not the JointState the log needs."""
    from rosbags.typesys import get_types_from_msg

    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg("int32 sec\nuint32 nanosec\n", "builtin_interfaces/msg/Time"))
    store.register(get_types_from_msg("builtin_interfaces/Time stamp\nstring frame_id\n", "std_msgs/msg/Header"))
    store.register(get_types_from_msg("std_msgs/Header header\nstring[] name\nfloat64[] position\n", JS))
    p = tmp_path / "bag"
    with Writer(p, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/joint_states", JS, typestore=store)
        for k in range(50):
            s = EPOCH_NS + k * PERIOD_NS
            stamp = store.types["builtin_interfaces/msg/Time"](sec=s // 10**9, nanosec=s % 10**9)
            header = store.types["std_msgs/msg/Header"](stamp=stamp, frame_id="")
            msg = store.types[JS](header=header, name=ARM, position=np.zeros(7))
            w.write(c, s, bytes(store.serialize_cdr(msg, JS)))
    for bulk in (True, False):
        with pytest.raises(DataError, match=r"bag: /joint_states message 0 \(bag time 1795435200\.000000000 s\) does "
                           r"not decode as sensor_msgs/msg/JointState: not the standard sensor_msgs/msg/JointState "
                           r"fields: .*velocity"):  # fmt: skip
            read_bag(p, joint_names=tuple(ARM), n_joints=None, joint_topic=None, wrench_topic=None, bulk=bulk)


def test_sqlite_rows_fetched_in_pieces_and_equal_receive_times_in_the_reference_order(tmp_path, monkeypatch):
    """The sqlite3 rows read from the messages table a few at a time (7 rows per fetch, 50 per block: pieces
    joined, blocks across fetches), with receive times shared by three messages each (ties, where the order
    is the storage order of rosbags' own query): the reference's messages, bit for bit, in its order."""
    from reflexarm.logs import _bag_messages

    rng = np.random.default_rng(3)
    p, n = tmp_path / "bag", 400
    values = rng.normal(size=(n, 3, 7))
    with Writer(p, version=9, storage_plugin=StoragePlugin.SQLITE3) as w:
        arm = w.add_connection("/joint_states", JS, typestore=STORE)
        ft = w.add_connection("/ft", WS, typestore=STORE)  # another topic's rows between the arm's
        for k in range(n):
            s = EPOCH_NS + k * PERIOD_NS
            names = ARM if k % 5 else ARM[::-1]
            msg = _joint_state(s, names, *values[k])
            w.write(arm, EPOCH_NS + (k // 3) * PERIOD_NS, _ser(msg, JS, k, "mixed"))
            w.write(ft, s, _ser(_wrench(s, values[k, 0, :6], "ft_sensor"), WS, k, "little"))
    monkeypatch.setattr(_bag_messages, "SQLITE_FETCH", 7)
    monkeypatch.setattr(_bag_messages, "BLOCK", 50)
    bulk, ref = _topic(p, "/joint_states", _cdr.JOINT_STATE, True), _topic(p, "/joint_states", _cdr.JOINT_STATE, False)
    assert bulk.received.size == n and bulk.n_bulk == n
    _assert_same_bits(bulk.received, ref.received, "receive times")
    assert [b.key for b in bulk.batches] == [b.key for b in ref.batches]
    for b, r in zip(bulk.batches, ref.batches, strict=True):
        for x, y in zip((b.msg_index, b.stamp, *b.arrays), (r.msg_index, r.stamp, *r.arrays), strict=True):
            _assert_same_bits(x, y, str(b.key))
    # the header stamps tell the ties apart: message k is the k-th written, in both
    stamps = np.concatenate([b.stamp for b in bulk.batches])[
        np.argsort(np.concatenate([b.msg_index for b in bulk.batches]))
    ]
    np.testing.assert_array_equal(stamps, EPOCH_NS + np.arange(n) * PERIOD_NS)
