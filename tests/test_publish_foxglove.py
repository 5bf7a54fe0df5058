"""FoxgloveSink: a real WebSocket client (the websockets package) speaks the Foxglove protocol
to the server on loopback, subscribes to every channel and decodes what arrives: protobuf
channels with the protobuf package from the schema the server advertises, JSON with json."""

from __future__ import annotations

import asyncio
import base64
import json
import math
import struct
import threading

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion.sinks.foxglove import FoxgloveSink
from fusion.sinks.ros_messages import Topics
from fusion.types.fused import FusedOdometry

pytestmark = pytest.mark.live  # real time: run alone (pyproject's markers)

pytest.importorskip("foxglove", reason="the Foxglove sink needs the 'foxglove' extra")
websockets = pytest.importorskip("websockets")
pytest.importorskip("google.protobuf")

TIMEOUT = 30.0  # generous: only reached if the server never delivers


def protobuf_class(schema_name: str, schema_b64: str):
    """Message class from an advertised FileDescriptorSet (base64), as a Foxglove client does."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64))
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def record(k: int) -> FusedOdometry:
    cov = np.diag([0.01 + k, 0.02, 99999, 99999, 99999, 0.03])
    cov[0, 5] = cov[5, 0] = 0.004  # x-yaw term: row major index 5 and 30
    cov[0, 1] = cov[1, 0] = -0.001  # x-y: index 1 and 6
    return FusedOdometry(
        t=100.25 + k, x=1.0 + k, y=-2.0, yaw=0.7, v=0.4, w=0.05, pose_covariance=cov,
        angular_velocity=[0.01, 0.02, 0.05], linear_acceleration=[0.1, -0.2, 9.8],
        orientation=[math.cos(0.35), 0.0, 0.0, math.sin(0.35)],
        wheel_left_speed=0.35, wheel_right_speed=0.45,
    )


class Publisher(threading.Thread):
    """Writes a record every 50 ms until told to stop (the client may subscribe late: the
    protocol has no acknowledgement, so keep publishing until everything has arrived)."""

    def __init__(self, sink: FoxgloveSink) -> None:
        super().__init__(daemon=True)
        self.sink, self.stop, self.sent = sink, threading.Event(), {}

    def run(self) -> None:
        k = 0
        while not self.stop.is_set() and k < 600:
            rec = record(k)
            self.sent[round(rec.t * 1e9)] = rec
            self.sink.write(rec)
            k += 1
            self.stop.wait(0.05)


async def client(port: int, want: set[str]) -> tuple[dict, dict]:
    """Connect, read the advertisement, subscribe to all, collect one message per topic."""
    uri = f"ws://127.0.0.1:{port}"
    async with websockets.connect(uri, subprotocols=["foxglove.sdk.v1"]) as ws:
        channels: dict[int, dict] = {}
        while set(c["topic"] for c in channels.values()) != want:
            msg = json.loads(await asyncio.wait_for(ws.recv(), TIMEOUT))
            if msg["op"] == "advertise":
                channels.update({c["id"]: c for c in msg["channels"]})
        subs = {i + 1: cid for i, cid in enumerate(sorted(channels))}
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": sid, "channelId": cid} for sid, cid in subs.items()]}))
        got: dict[str, tuple[int, bytes]] = {}
        while set(got) != want:
            frame = await asyncio.wait_for(ws.recv(), TIMEOUT)
            if isinstance(frame, str):
                continue
            # binary "message data": opcode 0x01, subscription id u32 LE, log time u64 LE
            opcode, sid, log_time = struct.unpack_from("<BIQ", frame, 0)
            assert opcode == 1
            topic = channels[subs[sid]]["topic"]
            got.setdefault(topic, (log_time, frame[13:]))
        return {c["topic"]: c for c in channels.values()}, got


def run_session(topics: Topics | None = None):
    sink = FoxgloveSink(port=0, topics=topics)
    sink.open()
    try:
        assert sink.port > 0
        want = {t for t in (topics or Topics()).as_dict().values() if t}
        pub = Publisher(sink)
        pub.start()
        try:
            channels, got = asyncio.run(client(sink.port, want))
        finally:
            pub.stop.set()
            pub.join(5)
    finally:
        sink.close()
    return channels, got, pub.sent


def test_foxglove_client_receives_and_decodes_every_channel() -> None:
    channels, got, sent = run_session()
    assert {t: (c["encoding"], c["schemaName"]) for t, c in channels.items()} == {
        "/odom": ("protobuf", "foxglove.Odometry"),
        "/tf": ("protobuf", "foxglove.FrameTransforms"),
        "/imu/data": ("json", "sensor_msgs/Imu"),
        "/wheel_left_speed": ("json", "std_msgs/Float32"),
        "/wheel_right_speed": ("json", "std_msgs/Float32"),
    }
    qx, qy, qz, qw = Rotation.from_euler("z", 0.7).as_quat()

    log_time, payload = got["/odom"]
    rec = sent[log_time]
    odom = protobuf_class("foxglove.Odometry", channels["/odom"]["schema"]).FromString(payload)
    assert odom.timestamp.seconds == math.floor(rec.t)
    assert abs(odom.timestamp.nanos - (rec.t % 1) * 1e9) <= 1
    assert (odom.frame_id, odom.body_frame_id) == ("odom", "base_footprint")
    assert (odom.pose.position.x, odom.pose.position.y, odom.pose.position.z) == (
        rec.x, -2.0, 0.0)
    o = odom.pose.orientation
    np.testing.assert_allclose([o.x, o.y, o.z, o.w], [qx, qy, qz, qw], atol=1e-12)
    assert (odom.linear_velocity.x, odom.linear_velocity.y) == (0.4, 0.0)
    assert odom.angular_velocity.z == 0.05
    cov = list(odom.pose_covariance)
    assert len(cov) == 36 and cov[0] == rec.pose_covariance[0, 0]
    assert cov[5] == cov[30] == 0.004 and cov[1] == cov[6] == -0.001 and cov[35] == 0.03
    assert list(odom.velocity_covariance) == rec.twist_covariance.reshape(36).tolist()

    log_time, payload = got["/tf"]
    rec = sent[log_time]
    tfs = protobuf_class("foxglove.FrameTransforms", channels["/tf"]["schema"]).FromString(
        payload)
    assert len(tfs.transforms) == 1
    tf = tfs.transforms[0]
    assert (tf.parent_frame_id, tf.child_frame_id) == ("odom", "base_footprint")
    assert (tf.translation.x, tf.translation.y) == (rec.x, -2.0)
    np.testing.assert_allclose([tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w],
                               [qx, qy, qz, qw], atol=1e-12)

    log_time, payload = got["/imu/data"]
    rec = sent[log_time]
    imu = json.loads(payload)
    assert imu["header"]["frame_id"] == "base_footprint"
    assert imu["header"]["stamp"] == {"sec": math.floor(rec.t), "nsec": 250_000_000}
    assert imu["orientation"] == pytest.approx({"x": 0, "y": 0, "z": qz, "w": qw}, abs=1e-12)
    assert imu["angular_velocity"] == {"x": 0.01, "y": 0.02, "z": 0.05}
    assert imu["linear_acceleration"] == {"x": 0.1, "y": -0.2, "z": 9.8}

    assert json.loads(got["/wheel_left_speed"][1]) == {"data": 0.35}
    assert json.loads(got["/wheel_right_speed"][1]) == {"data": 0.45}
    for topic in got:
        assert got[topic][0] in sent  # log time is the record's stamp in ns


def test_foxglove_custom_topics() -> None:
    topics = Topics(odom="/fused/odom", tf="/tf", imu=None, wheel_left=None, wheel_right=None)
    channels, got, _ = run_session(topics)
    assert sorted(channels) == ["/fused/odom", "/tf"]
    assert sorted(got) == ["/fused/odom", "/tf"]


def test_port_in_use_is_an_oserror_naming_it() -> None:
    with FoxgloveSink(port=0) as first:
        with pytest.raises(OSError, match=f"127.0.0.1:{first.port}"):
            FoxgloveSink(port=first.port).open()


def test_client_velocity_commands_reach_the_callback() -> None:
    """A client publishes geometry_msgs/Twist as JSON on /cmd_vel (what Foxglove's Teleop
    panel does): each valid one reaches on_cmd_vel(linear.x, angular.z)."""
    import queue

    got: queue.Queue = queue.Queue()
    sink = FoxgloveSink(port=0, on_cmd_vel=lambda v, w: got.put((v, w)))

    def frame(channel: int, payload: bytes) -> bytes:
        # client "message data": opcode 0x01, client channel id u32 LE, payload
        return struct.pack("<BI", 1, channel) + payload

    def twist(vx: float, wz: float) -> bytes:
        return json.dumps({"linear": {"x": vx, "y": 0.0, "z": 0.0},
                           "angular": {"x": 0.0, "y": 0.0, "z": wz}}).encode()

    async def client() -> dict:
        async with websockets.connect(f"ws://127.0.0.1:{sink.port}",
                                      subprotocols=["foxglove.sdk.v1"]) as ws:
            info = json.loads(await asyncio.wait_for(ws.recv(), TIMEOUT))
            assert info["op"] == "serverInfo"
            await ws.send(json.dumps({"op": "advertise", "channels": [
                {"id": 7, "topic": "/cmd_vel", "encoding": "json",
                 "schemaName": "geometry_msgs/Twist"},
                {"id": 8, "topic": "/other", "encoding": "json", "schemaName": "x"}]}))
            await ws.send(frame(8, twist(9.0, 9.0)))   # another topic: ignored
            await ws.send(frame(7, b"{not json"))      # malformed: rejected
            await ws.send(frame(7, twist(0.25, -0.5)))
            await ws.send(frame(7, twist(0.0, 1.5)))
            first = await asyncio.get_running_loop().run_in_executor(
                None, lambda: [got.get(timeout=TIMEOUT), got.get(timeout=TIMEOUT)])
            return {"info": info, "first": first}

    with sink:
        result = asyncio.run(client())
    assert "clientPublish" in result["info"]["capabilities"]
    assert result["first"] == [(0.25, -0.5), (0.0, 1.5)]
    assert got.empty()
    assert (sink.cmd_vel_received, sink.cmd_vel_rejected) == (2, 1)


def test_without_cmd_vel_the_server_refuses_client_publishing() -> None:
    async def client(port: int) -> dict:
        async with websockets.connect(f"ws://127.0.0.1:{port}",
                                      subprotocols=["foxglove.sdk.v1"]) as ws:
            return json.loads(await asyncio.wait_for(ws.recv(), TIMEOUT))

    with FoxgloveSink(port=0, cmd_vel_topic=None) as sink:
        info = asyncio.run(client(sink.port))
    assert "clientPublish" not in info["capabilities"]


def test_a_subscribing_client_causes_no_callback_errors(caplog) -> None:
    # regression: the server's listener lacked on_subscribe/on_unsubscribe, and the SDK
    # logged "Callback failed: AttributeError ..." for every channel a client subscribed to
    import logging

    caplog.set_level(logging.WARNING)
    _channels, got, _sent = run_session()
    assert len(got) == 5  # the client subscribed to every channel and got messages
    problems = [r.getMessage() for r in caplog.records
                if r.levelno >= logging.WARNING and r.name.startswith("foxglove")]
    assert problems == []
