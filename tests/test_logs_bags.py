"""Bag and MCAP readers of fusion.io on the bundled ROS 1 bag (robot_localization's
test2.bag of a simulated Jackal, datasets/rosbag/README.md) and on bags made here.

The facts checked on the real bag are properties of the recording, not of our code: message
counts, the 20 ms stamp grids, frame ids, gravity in the accelerometer, the IMU's attitude
agreeing with its own gyro and accelerometer, and the odometry's twist agreeing with the
derivative of its pose. Converted copies (ROS 2 sqlite3, ROS 2 MCAP, a lone .mcap file) must
read exactly the same."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion.io.bags import bag_topics, read_bag, read_bag_imu, read_bag_odometry, read_bag_twist
from fusion.io.errors import LogFormatError
from fusion.types.fused import FusedOdometry

pytest.importorskip("rosbags", reason="bag readers need the 'ros' extra")

IMU = "/imu/data"
ODOM = "/jackal_velocity_controller/odom"


@pytest.fixture(scope="module")
def bag_path(datasets_dir) -> Path:
    return datasets_dir / "rosbag" / "jackal_sim_test2.bag"


@pytest.fixture(scope="module")
def jackal(bag_path):
    return read_bag(bag_path, imu_topic=IMU, odom_topic=ODOM)


@pytest.fixture(scope="module")
def converted(bag_path, tmp_path_factory) -> dict[str, Path]:
    """The ROS 1 bag converted by rosbags' own converter to ROS 2 sqlite3 and MCAP bags, and
    the MCAP bag's data file alone."""
    from rosbags.convert import convert
    from rosbags.typesys import Stores, get_typestore

    base = tmp_path_factory.mktemp("converted")
    out = {}
    for storage in ("sqlite3", "mcap"):
        dst = base / f"jackal_{storage}"
        convert([bag_path], dst, storage, 8, None, "file", None,
                get_typestore(Stores.ROS2_JAZZY), [], [], [], [])
        out[storage] = dst
    (lone,) = out["mcap"].glob("*.mcap")
    out["lone_mcap"] = shutil.copy(lone, base / "jackal.mcap")
    return out


def test_topics_of_the_jackal_bag(bag_path) -> None:
    assert bag_topics(bag_path) == {
        IMU: ("sensor_msgs/Imu", 3061),
        ODOM: ("nav_msgs/Odometry", 3060),
    }


def test_jackal_stamps_counts_and_frames(jackal) -> None:
    imu, odom = jackal.imu, jackal.odometry
    assert len(imu) == 3061 and len(odom) == 3060
    # IMU stamps: exactly 47.58 s + k * 20 ms; odometry: the same grid shifted by 4 ms
    np.testing.assert_allclose(imu.t, 47.58 + 0.02 * np.arange(3061), atol=1e-9)
    np.testing.assert_allclose(odom.t, 47.584 + 0.02 * np.arange(3060), atol=1e-9)
    assert imu.out_of_order == odom.out_of_order == 0
    # the bag recorded each message 0..5 ms (IMU) and 0..32 ms (odometry) after its stamp
    for log, most in ((imu, 0.005), (odom, 0.032)):
        lag = log.bag_time - log.t
        assert lag.min() >= -1e-9 and lag.max() == pytest.approx(most, abs=1e-6)
    assert imu.frame_id == "base_link" and imu.topic == IMU
    assert (odom.frame_id, odom.child_frame_id) == ("odom", "base_link")


def test_jackal_imu_physics(jackal) -> None:
    imu, odom = jackal.imu, jackal.odometry
    # gravity: while the wheels report standing still, |accel| is g
    v = np.interp(imu.t, odom.t, odom.v)
    w = np.interp(imu.t, odom.t, odom.w)
    still = (np.abs(v) < 0.01) & (np.abs(w) < 0.01)
    assert still.sum() > 100
    norm = np.linalg.norm(imu.accel, axis=1)
    assert norm[still].mean() == pytest.approx(9.81, abs=0.02)
    assert np.median(norm) == pytest.approx(9.81, abs=0.05)
    # the attitude ([w, x, y, z], unit) agrees with the same message's gyro: body rates from
    # consecutive attitudes (scipy) correlate with the gyro on every axis
    assert imu.orientation is not None
    np.testing.assert_allclose(np.linalg.norm(imu.orientation, axis=1), 1.0, atol=1e-12)
    r = Rotation.from_quat(imu.orientation[:, [1, 2, 3, 0]])
    rates = (r[:-1].inv() * r[1:]).as_rotvec() / np.diff(imu.t)[:, None]
    for axis in range(3):
        assert np.corrcoef(rates[:, axis], imu.gyro[1:, axis])[0, 1] > 0.98
    # ... and with its accelerometer: specific force points along body "up" (median 1.8 deg)
    up = r.inv().apply([0.0, 0.0, 1.0])
    cos = np.sum(up * imu.accel / norm[:, None], axis=1)
    assert np.degrees(np.median(np.arccos(np.clip(cos, -1, 1)))) < 3.0


def test_jackal_odometry_twist_matches_its_pose(jackal) -> None:
    odom = jackal.odometry
    dt = np.diff(odom.t)
    dx, dy = np.diff(odom.x), np.diff(odom.y)
    # forward speed = displacement projected on the heading, per period
    v_pose = (dx * np.cos(odom.yaw[:-1]) + dy * np.sin(odom.yaw[:-1])) / dt
    assert np.corrcoef(v_pose, odom.v[1:])[0, 1] > 0.999
    assert np.median(np.abs(v_pose - odom.v[1:])) < 0.005
    # yaw rate = wrapped heading change per period
    w_pose = np.angle(np.exp(1j * np.diff(odom.yaw))) / dt
    assert np.corrcoef(w_pose, odom.w[1:])[0, 1] > 0.99
    assert np.all(np.abs(odom.yaw) <= math.pi)
    assert np.all(odom.vy == 0.0)  # a ground robot's controller reports no lateral speed
    assert np.sum(np.hypot(dx, dy)) == pytest.approx(84.2, abs=0.1)  # metres driven
    # covariance layout: 36 row major; diagonal (x, y, z, roll, pitch, yaw) as published
    assert odom.pose_covariance.shape == (3060, 36)
    np.testing.assert_array_equal(odom.pose_covariance[0].reshape(6, 6).diagonal(),
                                  [1e-3, 1e-3, 1e6, 1e6, 1e6, 0.03])
    np.testing.assert_array_equal(odom.twist_covariance[0].reshape(6, 6).diagonal(),
                                  [1e-3, 1e-3, 1e-3, 1e6, 1e6, 0.03])


@pytest.mark.parametrize("kind", ["sqlite3", "mcap", "lone_mcap"])
def test_ros2_bags_and_mcap_read_exactly_like_the_ros1_bag(jackal, converted, kind) -> None:
    log = read_bag(converted[kind], imu_topic=IMU, odom_topic=ODOM)
    assert log.topics == {IMU: ("sensor_msgs/Imu", 3061), ODOM: ("nav_msgs/Odometry", 3060)}
    for name in ("t", "gyro", "accel", "orientation", "bag_time"):
        np.testing.assert_array_equal(getattr(log.imu, name), getattr(jackal.imu, name))
    for name in ("t", "x", "y", "yaw", "v", "vy", "w", "pose_covariance",
                 "twist_covariance", "bag_time"):
        np.testing.assert_array_equal(getattr(log.odometry, name),
                                      getattr(jackal.odometry, name))
    assert (log.odometry.frame_id, log.odometry.child_frame_id) == ("odom", "base_link")


def test_bag_time_stamps(bag_path, jackal) -> None:
    imu = read_bag_imu(bag_path, IMU, stamps="bag")
    np.testing.assert_array_equal(imu.t, jackal.imu.bag_time)
    assert np.all(np.diff(imu.t) >= 0)


def test_missing_topic_lists_what_is_there(bag_path) -> None:
    with pytest.raises(LogFormatError) as err:
        read_bag_odometry(bag_path, "/odom")
    msg = str(err.value)
    assert str(bag_path) in msg and "'/odom'" in msg
    assert f"{IMU} (sensor_msgs/Imu, 3061 messages)" in msg
    assert f"{ODOM} (nav_msgs/Odometry, 3060 messages)" in msg


def test_wrong_type_is_named(bag_path) -> None:
    with pytest.raises(LogFormatError, match=f"topic {IMU} is sensor_msgs/Imu, expected "
                                             "nav_msgs/Odometry"):
        read_bag_odometry(bag_path, IMU)


def test_not_a_bag(tmp_path) -> None:
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 4)
    with pytest.raises(LogFormatError, match=f"{junk}: not a readable ROS bag"):
        read_bag_imu(junk)
    notmcap = tmp_path / "junk.mcap"
    notmcap.write_bytes(b"hello, world" * 10)
    with pytest.raises(LogFormatError, match=f"{notmcap}: not a readable MCAP"):
        read_bag_imu(notmcap)
    with pytest.raises(FileNotFoundError, match=r"nope\.bag"):
        read_bag_imu(tmp_path / "nope.bag")


def test_truncated_bag_is_an_error_naming_the_file(bag_path, tmp_path) -> None:
    cut = tmp_path / "cut.bag"
    cut.write_bytes(bag_path.read_bytes()[: bag_path.stat().st_size // 2])
    with pytest.raises(LogFormatError, match=str(cut)):
        read_bag_imu(cut, IMU)


def test_argument_checks(bag_path) -> None:
    with pytest.raises(ValueError, match="at least one"):
        read_bag(bag_path)
    with pytest.raises(ValueError, match="stamps"):
        read_bag(bag_path, imu_topic=IMU, stamps="wall")
    with pytest.raises(ValueError, match="two kinds"):
        read_bag(bag_path, imu_topic=IMU, odom_topic=IMU)


# -- bags written here -------------------------------------------------------------------


def _write_ros2(path: Path, topic: str, msgtype: str, messages: list) -> None:
    """A ROS 2 bag with ``messages`` = [(record time ns, message object)]."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    with Writer(path, version=8) as w:
        conn = w.add_connection(topic, msgtype, typestore=ts)
        for ns, msg in messages:
            w.write(conn, ns, ts.serialize_cdr(msg, msgtype))


def _types():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY).types


def _imu(T, sec: int, nsec: int, frame: str = "imu", gz: float = 0.1, no_q: bool = False):
    hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                                   frame_id=frame)
    V, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    cov = np.zeros(9)
    qcov = np.r_[-1.0, np.zeros(8)] if no_q else cov
    return T["sensor_msgs/msg/Imu"](
        header=hdr, orientation=Q(x=0.0, y=0.0, z=0.0, w=0.0 if no_q else 1.0),
        orientation_covariance=qcov, angular_velocity=V(x=0.0, y=0.0, z=gz),
        angular_velocity_covariance=cov, linear_acceleration=V(x=0.0, y=0.0, z=9.8),
        linear_acceleration_covariance=cov)


def test_out_of_order_stamps_are_sorted_and_counted(tmp_path) -> None:
    T = _types()
    secs = [10, 11, 10, 12, 13]
    nsecs = [0, 0, 500_000_000, 0, 0]
    msgs = [(i * 10**9, _imu(T, s, n, gz=float(i))) for i, (s, n) in
            enumerate(zip(secs, nsecs))]
    _write_ros2(tmp_path / "b", "/imu", "sensor_msgs/msg/Imu", msgs)
    log = read_bag_imu(tmp_path / "b", "/imu")
    assert log.out_of_order == 1
    np.testing.assert_array_equal(log.t, [10.0, 10.5, 11.0, 12.0, 13.0])
    np.testing.assert_array_equal(log.gyro[:, 2], [0.0, 2.0, 1.0, 3.0, 4.0])  # rows follow
    np.testing.assert_array_equal(log.bag_time, [0.0, 2.0, 1.0, 3.0, 4.0])
    np.testing.assert_array_equal(log.orientation, np.tile([1.0, 0, 0, 0], (5, 1)))


def test_imu_without_orientation_and_zero_stamps(tmp_path) -> None:
    T = _types()
    _write_ros2(tmp_path / "a", "/imu", "sensor_msgs/msg/Imu",
                [(5 * 10**9 + i, _imu(T, 1, i, no_q=True)) for i in range(3)])
    assert read_bag_imu(tmp_path / "a", "/imu").orientation is None
    _write_ros2(tmp_path / "z", "/imu", "sensor_msgs/msg/Imu",
                [(5 * 10**9 + i, _imu(T, 0, 0)) for i in range(3)])
    with pytest.raises(LogFormatError, match=r"every header\.stamp is zero.*stamps='bag'"):
        read_bag_imu(tmp_path / "z", "/imu")
    log = read_bag_imu(tmp_path / "z", "/imu", stamps="bag")
    np.testing.assert_array_equal(log.t, (5 * 10**9 + np.arange(3)) * 1e-9)


def test_changing_frame_id_and_non_finite_values_are_named(tmp_path) -> None:
    T = _types()
    _write_ros2(tmp_path / "f", "/imu", "sensor_msgs/msg/Imu",
                [(i, _imu(T, 1 + i, 0, frame="imu" if i < 2 else "imu2")) for i in range(3)])
    with pytest.raises(LogFormatError, match=r"topic /imu: frame_id changes from 'imu' to "
                                             r"'imu2' at message 3"):
        read_bag_imu(tmp_path / "f", "/imu")
    _write_ros2(tmp_path / "n", "/imu", "sensor_msgs/msg/Imu",
                [(i, _imu(T, 1 + i, 0, gz=math.nan if i == 1 else 0.0)) for i in range(3)])
    # one of three: more than a glitch, refused naming the first
    with pytest.raises(LogFormatError, match=r"topic /imu: 1 of its 3 messages have a "
                                             r"non-finite value \(more than 10%.*message 2 "
                                             r"\(t = 2.000000000 s\) has a non-finite value"):
        read_bag_imu(tmp_path / "n", "/imu")
    # one of twenty (an independent probe: one NaN gyro sample refused a 395 s bag): left
    # out, said, the others kept
    _write_ros2(tmp_path / "g", "/imu", "sensor_msgs/msg/Imu",
                [(i, _imu(T, 1 + i, 0, gz=math.nan if i == 7 else 0.0)) for i in range(20)])
    bag = read_bag(tmp_path / "g", imu_topic="/imu")
    np.testing.assert_array_equal(bag.imu.t, np.delete(np.arange(1.0, 21.0), 7))
    (note,) = bag.topic_notes
    assert "topic /imu: 1 message(s) with a non-finite value left out (the first: message 8 " \
        "(t = 8.000000000 s)" in note


def test_twist_from_ros1_and_twist_stamped_from_ros2(tmp_path) -> None:
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.typesys import Stores, get_typestore

    ts1 = get_typestore(Stores.ROS1_NOETIC)
    V = ts1.types["geometry_msgs/msg/Vector3"]
    Twist = ts1.types["geometry_msgs/msg/Twist"]
    cmds = [(0.5, 0.0, 0.25), (0.25, 0.0, -1.0), (0.0, 0.0, 0.0)]
    path = tmp_path / "cmd.bag"
    with Writer1(path) as w:
        conn = w.add_connection("/cmd_vel", "geometry_msgs/msg/Twist", typestore=ts1)
        for i, (v, vy, wz) in enumerate(cmds):
            msg = Twist(linear=V(x=v, y=vy, z=0.0), angular=V(x=0.0, y=0.0, z=wz))
            w.write(conn, (100 + i) * 10**9, ts1.serialize_ros1(msg, "geometry_msgs/msg/Twist"))
    log = read_bag_twist(path)  # Twist has no header: stamps are record times
    np.testing.assert_array_equal(log.t, [100.0, 101.0, 102.0])
    np.testing.assert_array_equal(log.v, [0.5, 0.25, 0.0])
    np.testing.assert_array_equal(log.w, [0.25, -1.0, 0.0])
    assert log.frame_id == ""

    T = _types()
    TS = T["geometry_msgs/msg/TwistStamped"]
    msgs = []
    for i, (v, _vy, wz) in enumerate(cmds):
        hdr = T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=7, nanosec=i * 1000), frame_id="base")
        tw = T["geometry_msgs/msg/Twist"](linear=T["geometry_msgs/msg/Vector3"](x=v, y=0.1,
                                                                                 z=0.0),
                                          angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0,
                                                                                  z=wz))
        msgs.append((50 * 10**9 + i, TS(header=hdr, twist=tw)))
    _write_ros2(tmp_path / "ts", "/cmd_vel_stamped", "geometry_msgs/msg/TwistStamped", msgs)
    log = read_bag_twist(tmp_path / "ts", "/cmd_vel_stamped")
    np.testing.assert_allclose(log.t, 7 + np.arange(3) * 1e-6, atol=1e-12)
    np.testing.assert_array_equal(log.vy, [0.1] * 3)
    np.testing.assert_array_equal(log.w, [0.25, -1.0, 0.0])
    assert log.frame_id == "base"


def test_fused_mcap_output_reads_back_as_odometry(tmp_path) -> None:
    """What fusion.sinks.bag.McapSink writes, read_bag_odometry reads (replaying fused output)."""
    from fusion.sinks.bag import McapSink

    recs = []
    for k in range(5):
        cov = np.diag([0.01 * (k + 1), 0.02, 99999, 99999, 99999, 0.003])
        cov[0, 5] = cov[5, 0] = 0.0001 * k
        recs.append(FusedOdometry(t=3.0 + 0.04 * k, x=0.1 * k, y=0.02 * k, yaw=3.0 - 0.5 * k,
                                  v=0.25, w=-0.5, pose_covariance=cov,
                                  linear_acceleration=[0.0, 0.0, 9.81]))
    out = tmp_path / "fused.mcap"
    with McapSink(out) as sink:
        for r in recs:
            sink.write(r)
    log = read_bag_odometry(out, "/odom")
    np.testing.assert_allclose(log.t, [r.t for r in recs], atol=1e-9)
    np.testing.assert_array_equal(log.x, [r.x for r in recs])
    np.testing.assert_array_equal(log.v, [0.25] * 5)
    np.testing.assert_array_equal(log.w, [-0.5] * 5)
    # yaw comes back wrapped to (-pi, pi]
    expected = np.angle(np.exp(1j * np.array([r.yaw for r in recs])))
    np.testing.assert_allclose(log.yaw, expected, atol=1e-12)
    np.testing.assert_array_equal(log.pose_covariance[3].reshape(6, 6),
                                  recs[3].pose_covariance)
    imu = read_bag_imu(out, "/imu/data")
    assert imu.orientation is None  # the records had no attitude: covariance[0] = -1
    # (an accelerometer, so an IMU; records with no IMU sample publish no /imu/data)
    assert imu.frame_id == "base_footprint"


def test_broken_ros2_bags_and_mcap_files_are_named(converted, tmp_path) -> None:
    empty = tmp_path / "not_a_bag"
    empty.mkdir()
    with pytest.raises(LogFormatError, match=f"{empty}: a folder without metadata.yaml"):
        read_bag_imu(empty)
    broken = tmp_path / "broken"
    shutil.copytree(converted["mcap"], broken)
    (broken / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    with pytest.raises(LogFormatError, match=f"{broken}: not a readable ROS bag"):
        read_bag_imu(broken, IMU)
    # an MCAP file cut short (a recorder killed mid-write) has no summary section: what is
    # complete is read (a prefix of the whole file's messages), and the log says so
    cut = tmp_path / "cut.mcap"
    data = Path(converted["lone_mcap"]).read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    whole = read_bag(converted["lone_mcap"], imu_topic=IMU).imu
    part = read_bag(cut, imu_topic=IMU)
    assert "unfinished MCAP recording" in part.note and str(cut) in part.note
    assert 0 < len(part.imu.t) < len(whole.t)
    np.testing.assert_array_equal(part.imu.gyro, whole.gyro[np.isin(whole.t, part.imu.t)])


def test_mcap_without_ros_channels_says_so(tmp_path) -> None:
    foxglove = pytest.importorskip("foxglove")
    path = tmp_path / "foxglove.mcap"
    ctx = foxglove.Context()
    writer = foxglove.open_mcap(path, context=ctx)
    foxglove.Channel("/imu/data", context=ctx).log({"x": 1}, log_time=1)
    writer.close()
    with pytest.raises(LogFormatError, match="no topic '/imu/data'; the file has no ROS topics"):
        read_bag_imu(path)


def test_a_ros1_bag_cut_short_is_named_with_the_way_out(datasets_dir, tmp_path) -> None:
    # a recorder killed mid-write leaves a ROS 1 bag without its index (or a .bag.active)
    data = (datasets_dir / "rosbag" / "jackal_sim_test2.bag").read_bytes()
    for name, way_out in (("cut.bag", "`rosbag reindex` rebuilds it"),
                          ("run.bag.active", "`rosbag reindex` it, then rename it to .bag")):
        cut = tmp_path / name
        cut.write_bytes(data[: len(data) // 2])
        with pytest.raises(LogFormatError, match=f"{cut}: not a readable ROS bag") as err:
            read_bag_imu(cut, "/imu/data")
        assert way_out in str(err.value)
    # and the replay takes the .bag.active for a bag (the same error, not "not a .bag")
    from fusion.jobs.replay import is_bag

    assert is_bag(tmp_path / "run.bag.active")
