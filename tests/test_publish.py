"""Sinks of fusion.sinks: JSON lines, rosbag2 and MCAP files (read back by independent
readers: rosbags' AnyReader, and the mcap package with mcap-ros2-support's CDR decoder)."""

from __future__ import annotations

import io
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion.sinks.bag import McapSink, Rosbag2Sink
from fusion.sinks.base import SinkError
from fusion.sinks.foxglove import FoxgloveSink
from fusion.sinks.registry import open_sink
from fusion.sinks.ros_messages import Topics, ros_messages
from fusion.sinks.text import CsvSink, JsonLinesSink
from fusion.types.fused import FusedOdometry

pytest.importorskip("rosbags", reason="bag sinks need the 'ros' extra")


def pose_cov(k: int) -> np.ndarray:
    """A symmetric covariance with distinct, recognisable entries: C[i][j] = 10*i + j + k/100
    on and above the diagonal (mirrored below), 99999 on z, roll, pitch."""
    c = np.zeros((6, 6))
    for i in range(6):
        for j in range(i, 6):
            c[i, j] = c[j, i] = 10 * i + j + k / 100
    c[2, 2] = c[3, 3] = c[4, 4] = 99999.0
    return c + 1000 * np.eye(6)  # diagonally dominant: a valid covariance


def make_records(n: int = 6) -> list[FusedOdometry]:
    recs = []
    for k in range(n):
        q = Rotation.from_euler("xyz", [0.02 * k, -0.01 * k, 0.3 + 0.1 * k]).as_quat()
        recs.append(FusedOdometry(
            t=47.58 + 0.02 * k, x=0.1 * k, y=-0.05 * k, yaw=0.3 + 0.1 * k, v=0.5 + 0.01 * k,
            w=0.1 - 0.02 * k, pose_covariance=pose_cov(k), twist_covariance=pose_cov(k + 50),
            orientation=[q[3], q[0], q[1], q[2]] if k % 2 == 0 else None,
            angular_velocity=[0.001 * k, -0.002 * k, 0.1 - 0.02 * k],
            linear_acceleration=[0.1 * k, 0.0, 9.81] if k % 3 != 2 else None,
            wheel_left_speed=0.45 + 0.01 * k if k != 4 else None,
            wheel_right_speed=0.55 + 0.01 * k if k != 4 else None,
        ))
    return recs


def expected_yaw_xyzw(yaw: float) -> np.ndarray:
    return Rotation.from_euler("z", yaw).as_quat()  # scipy: [x, y, z, w]


def check_stamp(stamp, t: float, sec_name: str = "sec", nsec_name: str = "nanosec") -> None:
    # independent split: integer seconds and the remainder in ns
    assert getattr(stamp, sec_name) == math.floor(t)
    assert abs(getattr(stamp, nsec_name) - (t - math.floor(t)) * 1e9) <= 1


def check_quat_xyzw(q, xyzw) -> None:
    got = np.array([q.x, q.y, q.z, q.w])
    got *= np.sign(np.dot(got, xyzw))
    np.testing.assert_allclose(got, xyzw, atol=1e-12)


def check_messages(rec: FusedOdometry, by_topic: dict) -> None:
    """Every field of the five messages of one record (attribute-style message objects)."""
    odom = by_topic["/odom"]
    check_stamp(odom.header.stamp, rec.t)
    assert odom.header.frame_id == "odom" and odom.child_frame_id == "base_footprint"
    p = odom.pose.pose.position
    assert (p.x, p.y, p.z) == (rec.x, rec.y, 0.0)
    check_quat_xyzw(odom.pose.pose.orientation, expected_yaw_xyzw(rec.yaw))
    cov = np.asarray(odom.pose.covariance)
    k = round((rec.t - 47.58) / 0.02)
    # row major: element (i, j) at 6*i + j; (0, 5) is the x-yaw term, (5, 0) its mirror
    assert cov[5] == cov[30] == 5 + k / 100
    assert cov[1] == cov[6] == 1 + k / 100
    assert cov[0] == 1000 + k / 100 and cov[14] == 99999 + 1000
    np.testing.assert_array_equal(cov.reshape(6, 6), pose_cov(k))
    np.testing.assert_array_equal(np.asarray(odom.twist.covariance).reshape(6, 6),
                                  pose_cov(k + 50))
    lin, ang = odom.twist.twist.linear, odom.twist.twist.angular
    assert (lin.x, lin.y, lin.z) == (rec.v, 0.0, 0.0)
    assert [ang.x, ang.y, ang.z] == rec.angular_velocity.tolist()

    tf = by_topic["/tf"]
    assert len(tf.transforms) == 1
    tr = tf.transforms[0]
    check_stamp(tr.header.stamp, rec.t)
    assert tr.header.frame_id == "odom" and tr.child_frame_id == "base_footprint"
    assert (tr.transform.translation.x, tr.transform.translation.y) == (rec.x, rec.y)
    assert tr.transform.translation.z == 0.0
    check_quat_xyzw(tr.transform.rotation, expected_yaw_xyzw(rec.yaw))

    if rec.orientation is None and rec.linear_acceleration is None:
        # no IMU sample behind it (wheels only): no sensor_msgs/Imu carrying the wheels' rate
        assert "/imu/data" not in by_topic
        imu = None
    else:
        imu = by_topic["/imu/data"]
        _check_imu(imu, rec)
    for topic, speed in (("/wheel_left_speed", rec.wheel_left_speed),
                         ("/wheel_right_speed", rec.wheel_right_speed)):
        if speed is None:
            assert topic not in by_topic
        else:
            assert by_topic[topic].data == pytest.approx(speed, rel=1e-7)  # float32


def _check_imu(imu, rec: FusedOdometry) -> None:
    check_stamp(imu.header.stamp, rec.t)
    assert imu.header.frame_id == "base_footprint"
    if rec.orientation is not None:
        w, x, y, z = rec.orientation
        check_quat_xyzw(imu.orientation, np.array([x, y, z, w]))
        assert list(imu.orientation_covariance) == [0.0] * 9
    else:  # sensor_msgs/Imu: -1 in element 0 says "no orientation estimate"
        assert imu.orientation_covariance[0] == -1.0
    av = imu.angular_velocity
    assert [av.x, av.y, av.z] == rec.angular_velocity.tolist()
    la = imu.linear_acceleration
    if rec.linear_acceleration is not None:
        assert [la.x, la.y, la.z] == rec.linear_acceleration.tolist()
        assert imu.linear_acceleration_covariance[0] == 0.0
    else:
        assert imu.linear_acceleration_covariance[0] == -1.0


def group_by_stamp(messages) -> dict[int, dict]:
    """[(topic, log_time_ns, msg)] -> {log_time_ns: {topic: msg}}, no topic twice."""
    out: dict[int, dict] = {}
    for topic, ns, msg in messages:
        slot = out.setdefault(ns, {})
        assert topic not in slot, f"two {topic} messages at {ns}"
        slot[topic] = msg
    return out


def read_rosbag2(path: Path) -> list:
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as reader:
        return [(c.topic, ns, reader.deserialize(raw, c.msgtype))
                for c, ns, raw in reader.messages()]


def read_mcap_independently(path: Path) -> tuple[list, dict]:
    """The mcap package and mcap-ros2-support's CDR decoder (no rosbags code involved)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        types = {c.topic: (c.message_encoding, summary.schemas[c.schema_id].name,
                           summary.schemas[c.schema_id].encoding)
                 for c in summary.channels.values()}
        msgs = [(ch.topic, m.log_time, dec) for _s, ch, m, dec in reader.iter_decoded_messages()]
    return msgs, types


EXPECTED_TYPES = {
    "/odom": ("cdr", "nav_msgs/msg/Odometry", "ros2msg"),
    "/tf": ("cdr", "tf2_msgs/msg/TFMessage", "ros2msg"),
    "/imu/data": ("cdr", "sensor_msgs/msg/Imu", "ros2msg"),
    "/wheel_left_speed": ("cdr", "std_msgs/msg/Float32", "ros2msg"),
    "/wheel_right_speed": ("cdr", "std_msgs/msg/Float32", "ros2msg"),
}


def write_all(sink, records) -> None:
    with sink:
        for r in records:
            sink.write(r)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_rosbag2_sink_reads_back_with_rosbags(tmp_path: Path, storage: str) -> None:
    recs = make_records()
    bag = tmp_path / "fused"
    write_all(Rosbag2Sink(bag, storage=storage), recs)
    assert (bag / "metadata.yaml").is_file()
    msgs = read_rosbag2(bag)
    # 5 topics per record, minus the two wheel speeds of record 4 and the IMU of record 5
    # (neither attitude nor acceleration: no IMU sample)
    assert len(msgs) == 5 * len(recs) - 3
    grouped = group_by_stamp(msgs)
    assert sorted(grouped) == [round(r.t * 1e9) for r in recs]
    for rec in recs:
        check_messages(rec, grouped[round(rec.t * 1e9)])
    assert [p.name for p in tmp_path.iterdir()] == ["fused"]  # no temporary left behind


@pytest.mark.parametrize("compression", ["zstd", None])
def test_mcap_sink_reads_back_with_mcap_and_its_ros2_decoder(tmp_path: Path,
                                                              compression) -> None:
    from mcap.reader import make_reader

    recs = make_records()
    out = tmp_path / "fused.mcap"
    write_all(McapSink(out, compression=compression), recs)
    with out.open("rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert chunks and {c.compression for c in chunks} == {compression or ""}
    msgs, types = read_mcap_independently(out)
    assert types == EXPECTED_TYPES
    assert len(msgs) == 5 * len(recs) - 3
    grouped = group_by_stamp(msgs)
    for rec in recs:
        check_messages(rec, grouped[round(rec.t * 1e9)])
    assert [p.name for p in tmp_path.iterdir()] == ["fused.mcap"]
    # deterministic: the same records give the same bytes (golden-output tests rely on it)
    first = out.read_bytes()
    write_all(McapSink(out, compression=compression), recs)
    assert out.read_bytes() == first


def test_custom_topics_and_frames(tmp_path: Path) -> None:
    topics = Topics(odom="/robot/odom", tf="/tf", imu=None, wheel_left=None, wheel_right=None)
    rec = FusedOdometry(t=1.5, x=1, y=2, yaw=-1, v=0, w=0, frame_id="odom2",
                        child_frame_id="base_link", wheel_left_speed=1.0)
    out = tmp_path / "f.mcap"
    write_all(McapSink(out, topics=topics), [rec])
    msgs, types = read_mcap_independently(out)
    assert sorted(types) == ["/robot/odom", "/tf"]
    by_topic = {t: m for t, _ns, m in msgs}
    assert by_topic["/robot/odom"].header.frame_id == "odom2"
    assert by_topic["/robot/odom"].child_frame_id == "base_link"
    assert by_topic["/tf"].transforms[0].child_frame_id == "base_link"
    check_stamp(by_topic["/tf"].transforms[0].header.stamp, 1.5)


def test_mcap_sink_failure_keeps_the_existing_file(tmp_path: Path) -> None:
    out = tmp_path / "fused.mcap"
    out.write_bytes(b"the previous, complete output")
    with pytest.raises(RuntimeError, match="pipeline failed"):
        with McapSink(out) as sink:
            for r in make_records(3):
                sink.write(r)
            raise RuntimeError("pipeline failed")
    assert out.read_bytes() == b"the previous, complete output"
    assert [p.name for p in tmp_path.iterdir()] == ["fused.mcap"]
    # a complete run replaces it
    write_all(McapSink(out), make_records(2))
    assert len(read_mcap_independently(out)[0]) == 10


def test_negative_stamp_aborts_and_names_the_value(tmp_path: Path) -> None:
    out = tmp_path / "fused.mcap"
    with pytest.raises(ValueError, match=r"cannot be negative, got t = -0.5"):
        write_all(McapSink(out), [FusedOdometry(t=-0.5, x=0, y=0, yaw=0, v=0, w=0)])
    assert list(tmp_path.iterdir()) == []


def test_rosbag2_sink_refuses_existing_bag_unless_overwrite(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    write_all(Rosbag2Sink(bag), make_records(1))
    before = sorted((p.name, p.stat().st_size) for p in bag.iterdir())
    with pytest.raises(FileExistsError, match=f"{bag}: exists"):
        Rosbag2Sink(bag).open()
    # overwrite allowed, but the run fails: the old bag stays as it was
    with pytest.raises(KeyError):
        with Rosbag2Sink(bag, overwrite=True) as sink:
            sink.write(make_records(1)[0])
            raise KeyError("boom")
    assert sorted((p.name, p.stat().st_size) for p in bag.iterdir()) == before
    write_all(Rosbag2Sink(bag, overwrite=True), make_records(3))
    assert len(read_rosbag2(bag)) == 15
    assert [p.name for p in tmp_path.iterdir()] == ["bag"]


def test_compression_choices() -> None:
    assert Rosbag2Sink("b").compression == "zstd"
    assert Rosbag2Sink("b", storage="sqlite3").compression is None
    with pytest.raises(ValueError, match="MCAP storage only"):
        Rosbag2Sink("b", storage="sqlite3", compression="zstd")
    with pytest.raises(ValueError, match="compression"):
        McapSink("f.mcap", compression="lz4")


def test_missing_output_folder_is_named(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="does not exist"):
        McapSink(tmp_path / "nope" / "f.mcap").open()


def test_jsonl_to_stream_one_object_per_line() -> None:
    recs = make_records(3)
    buf = io.StringIO()
    write_all(JsonLinesSink(buf), recs)
    lines = buf.getvalue().splitlines()
    assert len(lines) == 3
    for line, rec in zip(lines, recs):
        d = json.loads(line)
        assert d["t"] == rec.t and d["x"] == rec.x and d["yaw"] == rec.yaw
        assert d["pose_covariance"][5] == rec.pose_covariance[0, 5]
        assert FusedOdometry.from_dict(d) == rec
    assert not buf.closed  # the caller's stream stays open


def test_jsonl_default_is_stdout(capsys) -> None:
    write_all(JsonLinesSink(), make_records(2))
    out = capsys.readouterr().out.splitlines()
    assert [json.loads(s)["t"] for s in out] == [47.58, 47.6]


def test_jsonl_to_path_is_atomic(tmp_path: Path) -> None:
    out = tmp_path / "fused.jsonl"
    out.write_text("old\n")
    with pytest.raises(OSError):
        with JsonLinesSink(out) as sink:
            sink.write(make_records(1)[0])
            raise OSError("disk gone")
    assert out.read_text() == "old\n"
    write_all(JsonLinesSink(out), make_records(4))
    assert len(out.read_text().splitlines()) == 4
    assert os.listdir(tmp_path) == ["fused.jsonl"]


def test_sink_order_of_operations() -> None:
    sink = JsonLinesSink(io.StringIO())
    with pytest.raises(SinkError, match="not open"):
        sink.write(make_records(1)[0])
    sink.open()
    with pytest.raises(SinkError, match="already opened"):
        sink.open()
    with pytest.raises(TypeError, match="FusedOdometry"):
        sink.write({"t": 0})  # type: ignore[arg-type]
    sink.close()
    sink.close()  # idempotent
    with pytest.raises(SinkError, match="state closed"):
        sink.write(make_records(1)[0])


def test_ros_messages_order_and_skips() -> None:
    rec = make_records(5)[4]  # no wheel speeds
    keys = [k for k, *_ in ros_messages(rec)]
    assert keys == ["odom", "tf", "imu"]
    keys = [k for k, *_ in ros_messages(make_records(1)[0], Topics(tf=None, imu=None))]
    assert keys == ["odom", "wheel_left", "wheel_right"]


@pytest.mark.parametrize("bad", [
    {"odom": "odom"}, {"tf": "/odom"}, {"imu": "/imu/"},
])
def test_topics_validation(bad: dict) -> None:
    with pytest.raises(ValueError, match="topic names"):
        Topics(**bad)


def test_open_sink_specs(tmp_path: Path) -> None:
    assert isinstance(open_sink("jsonl"), JsonLinesSink)
    s = open_sink(f"mcap:{tmp_path}/a.mcap")
    assert isinstance(s, McapSink) and s.path == tmp_path / "a.mcap"
    s = open_sink(f"rosbag2:{tmp_path}/bag")
    assert type(s) is Rosbag2Sink and s.storage == "mcap"
    s = open_sink("foxglove")
    assert isinstance(s, FoxgloveSink) and (s.host, s.port) == ("127.0.0.1", 8765)
    s = open_sink("foxglove:9001")
    assert (s.host, s.port) == ("127.0.0.1", 9001)
    s = open_sink("foxglove:0.0.0.0:9002")
    assert (s.host, s.port) == ("0.0.0.0", 9002)
    s = open_sink(f"csv:{tmp_path}/f.csv")
    assert isinstance(s, CsvSink) and s.path == tmp_path / "f.csv"
    with pytest.raises(ValueError, match="unknown sink 'tsv:x'"):
        open_sink("tsv:x")
    with pytest.raises(ValueError, match="give a path"):
        open_sink("csv")
    with pytest.raises(ValueError, match="give a path"):
        open_sink("mcap")
    with pytest.raises(ValueError, match="foxglove"):
        open_sink("foxglove:host:notaport")


def test_csv_sink_columns_values_and_atomicity(tmp_path: Path) -> None:
    import csv

    recs = make_records(6)
    recs[1] = FusedOdometry(**{**recs[1].__dict__, "yaw": 3 * math.pi / 2})  # wraps to -pi/2
    out = tmp_path / "fused.csv"
    out.write_text("old\n")
    with pytest.raises(RuntimeError):
        with CsvSink(out) as sink:
            sink.write(recs[0])
            raise RuntimeError("stop")
    assert out.read_text() == "old\n"
    write_all(CsvSink(out), recs)
    with out.open() as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0])[:6] == ["t", "x", "y", "yaw", "v", "w"]
    assert len(rows) == 6
    for row, rec in zip(rows, recs):
        k = round((rec.t - 47.58) / 0.02)
        assert float(row["t"]) == rec.t and float(row["x"]) == rec.x
        assert float(row["v"]) == rec.v and float(row["w"]) == rec.w
        # pose_cov(k): C[i][j] = 10 i + j + k/100 (+1000 on the diagonal); x=0, y=1, yaw=5
        assert float(row["var_x"]) == 1000 + k / 100
        assert float(row["var_yaw"]) == 55 + 1000 + k / 100
        assert float(row["cov_xy"]) == 1 + k / 100
        assert float(row["cov_x_yaw"]) == 5 + k / 100
        assert float(row["cov_y_yaw"]) == 15 + k / 100
        # twist_covariance is pose_cov(k + 50)
        assert float(row["var_w"]) == 55 + 1000 + (k + 50) / 100
        if rec.wheel_left_speed is None:
            assert row["wheel_left_speed"] == row["wheel_right_speed"] == ""
        else:
            assert float(row["wheel_right_speed"]) == rec.wheel_right_speed
    assert float(rows[1]["yaw"]) == pytest.approx(-math.pi / 2, abs=1e-15)
    assert float(rows[0]["yaw"]) == 0.3
    first = out.read_bytes()
    write_all(CsvSink(out), recs)
    assert out.read_bytes() == first  # byte-identical for the same records
