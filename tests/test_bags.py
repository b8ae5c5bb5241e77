"""ROS 2 bags (MCAP, rosbag2 sqlite3) written with rosbags' own writer, read as robot logs: topics found
or chosen, joints mapped by name per message, gripper messages left out, header stamps against receive
times, the wrist wrench interpolated at the joint stamps."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from log_exports import EPOCH_NS, write_bag
from reflexarm.errors import DataError
from reflexarm.ident import RobotLog, load_log

NAMES = ["j1", "j2", "j3"]
#: Bag values are float64 written and read back unchanged; times are integer ns made relative: equal
#: to the log's k * 1e-3 s within a few ulp.
TIME_ATOL = 1e-15


def _log(n=200, wrench=None):
    t = np.arange(n) * 1e-3
    w = 2 * np.pi * np.array([0.5, 0.8, 1.1])
    tau = np.random.default_rng(0).normal(size=(n, 3))
    return RobotLog(t, np.sin(np.outer(t, w)), np.cos(np.outer(t, w)) * w, tau, wrench=wrench)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_joint_states_by_name_with_a_gripper_in_its_own_messages(tmp_path, storage):
    log = _log()
    p = write_bag(log, tmp_path / "bag", NAMES[::-1], storage=storage)  # the bag's first order is reversed
    back = load_log(p, joint_names=NAMES[::-1])
    np.testing.assert_allclose(back.t, log.t, rtol=0, atol=TIME_ATOL)
    np.testing.assert_array_equal(back.q, log.q)
    np.testing.assert_array_equal(back.tau, log.tau)
    text = "\n".join(back.notes)
    assert "bag: joints from topic /joint_states (sensor_msgs/msg/JointState, the bag's only one)" in text
    assert "the joint order changes between /joint_states messages; mapped by name per message" in text
    assert "left out 20 /joint_states message(s) holding none of the arm's joints" in text
    # a single storage file is read as well as the folder
    (single,) = p.glob("*.mcap" if storage == "mcap" else "*.db3")
    np.testing.assert_array_equal(load_log(single, joint_names=NAMES[::-1]).q, log.q)


def test_joint_names_pick_the_model_order(tmp_path):
    log = _log()
    p = write_bag(log, tmp_path / "bag", NAMES, storage="mcap", gripper=False)
    back = load_log(p, joint_names=["j3", "j1", "j2"])
    np.testing.assert_array_equal(back.q, log.q[:, [2, 0, 1]])
    unnamed = load_log(p)  # without names: the first message's order, said so
    assert "bag: joint order taken from the first message: j1, j2, j3" in unnamed.notes


def test_receive_times_when_header_stamps_are_unset(tmp_path):
    log = _log()
    p = write_bag(log, tmp_path / "bag", NAMES, storage="mcap", gripper=False, start_ns=0, receive_delay_ns=10**9)
    back = load_log(p, joint_names=NAMES)
    assert "bag: the /joint_states header stamps are unset (zero); times from the bag's receive times" in "\n".join(
        back.notes
    )
    np.testing.assert_allclose(back.t, log.t, rtol=0, atol=TIME_ATOL)


def test_messages_recorded_out_of_order_are_sorted_by_stamp(tmp_path):
    log = _log()
    order = np.arange(len(log))
    order[[50, 51, 120, 121]] = order[[51, 50, 121, 120]]  # two pairs arrive swapped
    p = write_bag(log, tmp_path / "bag", NAMES, storage="mcap", sample_order=order)
    back = load_log(p, joint_names=NAMES)
    np.testing.assert_array_equal(back.q, log.q)
    np.testing.assert_allclose(back.t, log.t, rtol=0, atol=TIME_ATOL)
    assert "bag: 4 /joint_states message(s) were recorded out of stamp order; sorted by stamp" in back.notes


def test_without_joint_names_the_first_message_with_the_robots_joint_count_gives_the_order(tmp_path):
    log = _log()
    p = write_bag(log, tmp_path / "bag", NAMES, storage="mcap")  # the bag's first message is the gripper's
    back = load_log(p, n_joints=3)
    np.testing.assert_array_equal(back.q, log.q)
    assert "bag: joint order taken from the first message with 3 joints: j1, j2, j3" in back.notes


def test_wrench_is_interpolated_at_the_joint_stamps(tmp_path):
    """A wrench linear in time (so linear interpolation is exact) on its own topic; the joint samples
    outside its time span are dropped and counted."""
    n = 200
    t = np.arange(n) * 1e-3
    wrench = np.outer(t, [1.0, -2.0, 3.0, 0.1, 0.2, -0.3]) + np.array([5.0, 0, 0, 0, 0, 1.0])
    log = _log(n, wrench=wrench)
    p = write_bag(log, tmp_path / "bag", NAMES, storage="sqlite3", wrench_topic="/ft", gripper=False)
    back = load_log(p, joint_names=NAMES, wrench_topic="/ft")
    np.testing.assert_allclose(back.wrench, wrench, rtol=0, atol=1e-12)
    assert "bag: wrist wrench from /ft (geometry_msgs/msg/WrenchStamped, 200 messages, 1000 Hz, frame 'ft_sensor')" in (
        "\n".join(back.notes)
    )
    # the joints of a second bag with the wrench only from 20 ms on, at a quarter of the rate and 0.5 ms
    # off the joint stamps
    p2 = write_bag(log, tmp_path / "bag2", NAMES, storage="mcap", gripper=False)
    store = get_typestore(Stores.ROS2_HUMBLE)
    W = store.types
    with Writer(tmp_path / "bag3", version=9) as writer:
        js = writer.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=store)
        ft = writer.add_connection("/ft", "geometry_msgs/msg/WrenchStamped", typestore=store)
        with AnyReader([p2]) as reader:
            for _, stamp, raw in reader.messages():
                writer.write(js, stamp, raw)
        for k in range(20, n, 4):
            s = EPOCH_NS + k * 1_000_000 + 500_000
            ts = (s - EPOCH_NS) * 1e-9
            f = np.array([1.0, -2.0, 3.0, 0.1, 0.2, -0.3]) * ts + np.array([5.0, 0, 0, 0, 0, 1.0])
            msg = W["geometry_msgs/msg/WrenchStamped"](
                header=W["std_msgs/msg/Header"](
                    stamp=W["builtin_interfaces/msg/Time"](sec=s // 10**9, nanosec=s % 10**9), frame_id="tool0"
                ),
                wrench=W["geometry_msgs/msg/Wrench"](
                    force=W["geometry_msgs/msg/Vector3"](x=f[0], y=f[1], z=f[2]),
                    torque=W["geometry_msgs/msg/Vector3"](x=f[3], y=f[4], z=f[5]),
                ),
            )
            writer.write(ft, s, store.serialize_cdr(msg, "geometry_msgs/msg/WrenchStamped"))
    back = load_log(tmp_path / "bag3", joint_names=NAMES, wrench_topic="/ft")
    inside = (t >= 0.0205) & (t <= (20 + 4 * ((n - 21) // 4)) * 1e-3 + 0.0005)
    assert len(back) == int(inside.sum())
    np.testing.assert_allclose(back.wrench, wrench[inside], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(back.q, log.q[inside])
    text = "\n".join(back.notes)
    assert f"dropped {int((~inside).sum())} joint samples outside the wrench's time span" in text
    assert "frame 'tool0'" in text


def test_topic_choice_and_its_errors(tmp_path):
    log = _log(wrench=np.zeros((200, 6)))
    p = write_bag(log, tmp_path / "bag", NAMES, storage="mcap", wrench_topic="/ft", gripper=False)
    back = load_log(p, joint_names=NAMES)
    assert "bag: geometry_msgs/msg/WrenchStamped topic(s) /ft not used (no wrench topic given)" in back.notes
    assert back.wrench is None
    topics = r"topics: /ft \(geometry_msgs/msg/WrenchStamped\), /joint_states \(sensor_msgs/msg/JointState\)"
    with pytest.raises(DataError, match=r"bag: no topic '/joint' in the bag; " + topics) as info:
        load_log(p, joint_names=NAMES, joint_topic="/joint")
    assert (info.value.column, info.value.expected) == ("/joint", ("/ft", "/joint_states"))
    with pytest.raises(DataError, match=r"bag: topic '/ft' carries geometry_msgs/msg/WrenchStamped, not sensor_msgs"):
        load_log(p, joint_names=NAMES, joint_topic="/ft")
    with pytest.raises(
        DataError, match=r"bag: the first /joint_states message has 3 joints \(j1, j2, j3\); the robot has 7"
    ):
        load_log(p, n_joints=7)


def test_a_message_missing_an_arm_joint_or_its_effort_is_refused(tmp_path):
    log = _log()
    p = write_bag(log, tmp_path / "bag", NAMES, storage="mcap", gripper=False)
    with pytest.raises(DataError, match=r"bag: /joint_states message 0 holds joints j1, j2, j3: the arm's "
                       r"joint\(s\) 'j4' missing \(a message must hold all of the arm's joints or none\)"):  # fmt: skip
        load_log(p, joint_names=[*NAMES, "j4"])
    p2 = write_bag(log, tmp_path / "bag2", NAMES, storage="mcap", effort=False)
    with pytest.raises(DataError, match=r"bag2: /joint_states message 1 has 0 effort values for 3 joints; the arm's "
                       r"effort is required"):  # fmt: skip
        load_log(p2, joint_names=NAMES)
    p3 = write_bag(log, tmp_path / "bag3", NAMES, storage="mcap", gripper=True)
    assert len(load_log(p3, joint_names=NAMES)) == len(log)  # the gripper's empty velocity/effort do not matter


def test_not_a_bag(tmp_path):
    p = tmp_path / "x.mcap"
    p.write_bytes(b"not a bag")
    with pytest.raises(DataError, match=r"x\.mcap: cannot read the file as a ROS 2 bag"):
        load_log(p)
