"""A live Foxglove WebSocket server for the fused odometry (``foxglove`` extra); its /cmd_vel
(the Teleop panel) reaches an ``on_cmd_vel`` callback.
"""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Callable
from typing import Any

from fusion.sinks.base import Sink, _need
from fusion.sinks.ros_messages import Topics, ros_messages, stamp_ns
from fusion.types.fused import FusedOdometry

__all__ = ["FoxgloveSink"]


# JSON schemas of the Foxglove sink's JSON channels (ROS field names, so layouts carry over).
_IMU_SCHEMA = {
    "title": "sensor_msgs/Imu",
    "type": "object",
    "properties": {
        "header": {"type": "object"},
        "orientation": {"type": "object"},
        "orientation_covariance": {"type": "array", "items": {"type": "number"}},
        "angular_velocity": {"type": "object"},
        "angular_velocity_covariance": {"type": "array", "items": {"type": "number"}},
        "linear_acceleration": {"type": "object"},
        "linear_acceleration_covariance": {"type": "array", "items": {"type": "number"}},
    },
}


_FLOAT32_SCHEMA = {"title": "std_msgs/Float32", "type": "object",
                   "properties": {"data": {"type": "number"}}}


def _json_header(fields: dict[str, Any]) -> dict[str, Any]:
    """Stamp ns -> ``{"sec", "nsec"}`` (Foxglove's JSON time) inside a message dict."""
    out = dict(fields)
    sec, nsec = divmod(out["header"]["stamp"], 1_000_000_000)
    out["header"] = {**out["header"], "stamp": {"sec": sec, "nsec": nsec}}
    return out


class FoxgloveSink(Sink):
    """A Foxglove WebSocket server (``foxglove-sdk``) streaming the fused odometry live.

    Channels (names from :class:`Topics`):

    - ``/odom``: ``foxglove.Odometry`` (protobuf): pose in ``frame_id`` with the yaw-only
      quaternion, linear velocity ``(v, 0, 0)`` m/s and angular velocity rad/s in the body
      frame, both 6x6 covariances row major.
    - ``/tf``: ``foxglove.FrameTransforms`` (protobuf): ``frame_id`` -> ``child_frame_id``.
    - ``/imu/data``: JSON with sensor_msgs/Imu's fields.
    - ``/wheel_left_speed``, ``/wheel_right_speed``: JSON ``{"data": m/s}``.

    Every message is logged with ``log_time`` = the record's stamp in ns. Open Foxglove and
    connect to ``ws://HOST:PORT``.

    Velocity commands: the server accepts client publishing (JSON) and hands each
    geometry_msgs/Twist a client sends on ``cmd_vel_topic`` (Foxglove's Teleop panel does) to
    ``on_cmd_vel(linear.x m/s, angular.z rad/s)``, like the ROS 1 node's /cmd_vel. It runs on
    the server's thread; malformed messages are counted in :attr:`cmd_vel_rejected`.

    Args:
        host: address to bind; default loopback. Binding to all interfaces (``0.0.0.0``)
            exposes the stream, and the command channel, to the network: do it deliberately.
        port: TCP port; 0 picks a free one (read it from :attr:`port` after ``open()``).
        topics: channel names.
        name: server name shown in the client.
        cmd_vel_topic: topic of client velocity commands, or None to refuse client publishing.
        on_cmd_vel: ``callback(v, w)`` for each valid command.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 8765, *,
                 topics: Topics | None = None, name: str = "diffbot-fusion",
                 cmd_vel_topic: str | None = "/cmd_vel",
                 on_cmd_vel: Callable[[float, float], None] | None = None) -> None:
        super().__init__()
        if not 0 <= int(port) <= 65535:
            raise ValueError(f"port must be 0..65535, got {port}")
        self.host = host
        self._port = int(port)
        self.topics = topics or Topics()
        self.name = name
        self.cmd_vel_topic = cmd_vel_topic
        self.on_cmd_vel = on_cmd_vel
        self.cmd_vel_received = 0
        self.cmd_vel_rejected = 0
        self._client_channels: dict[tuple[int, int], tuple[str, str]] = {}
        self._server: Any = None
        self._channels: dict[str, Any] = {}

    def __repr__(self) -> str:
        return f"FoxgloveSink({self.host}:{self._port})"

    @property
    def port(self) -> int:
        """The TCP port the server listens on (the chosen one when opened with 0)."""
        return self._server.port if self._server is not None else self._port

    def _open(self) -> None:
        foxglove = _need("foxglove", "foxglove")
        channels = _need("foxglove.channels", "foxglove")
        ctx = foxglove.Context()
        extra: dict[str, Any] = {}
        if self.cmd_vel_topic is not None:
            from foxglove.websocket import Capability, ServerListener

            # the SDK's ServerListener gives every callback we do not handle (on_subscribe,
            # on_unsubscribe, ...) its documented no-op; without it each client subscription
            # logged "Callback failed: AttributeError"
            listener = type("_Listener", (_CommandListener, ServerListener), {})(self)
            extra = {"capabilities": [Capability.ClientPublish],
                     "supported_encodings": ["json"],
                     "server_listener": listener}
        try:
            self._server = foxglove.start_server(name=self.name, host=self.host,
                                                 port=self._port, context=ctx, **extra)
        except Exception as exc:
            raise OSError(f"Foxglove server on {self.host}:{self._port}: {exc}") from exc
        t = self.topics
        if t.odom:
            self._channels["odom"] = channels.OdometryChannel(t.odom, context=ctx)
        if t.tf:
            self._channels["tf"] = channels.FrameTransformsChannel(t.tf, context=ctx)
        if t.imu:
            self._channels["imu"] = foxglove.Channel(t.imu, schema=_IMU_SCHEMA, context=ctx)
        for key in ("wheel_left", "wheel_right"):
            topic = getattr(t, key)
            if topic:
                self._channels[key] = foxglove.Channel(topic, schema=_FLOAT32_SCHEMA,
                                                       context=ctx)
        self._ctx = ctx

    def _write(self, record: FusedOdometry) -> None:
        from foxglove import messages as fm

        ns = stamp_ns(record.t)
        sec, nsec = divmod(ns, 1_000_000_000)
        stamp = fm.Timestamp(sec=sec, nsec=nsec)
        qw, qx, qy, qz = (float(v) for v in record.yaw_quaternion)
        position = fm.Vector3(x=record.x, y=record.y, z=0.0)
        rotation = fm.Quaternion(x=qx, y=qy, z=qz, w=qw)
        ch = self._channels
        if "odom" in ch:
            wx, wy, wz = (float(v) for v in record.angular_velocity)
            ch["odom"].log(fm.Odometry(
                timestamp=stamp, frame_id=record.frame_id, body_frame_id=record.child_frame_id,
                pose=fm.Pose(position=position, orientation=rotation),
                linear_velocity=fm.Vector3(x=record.v, y=0.0, z=0.0),
                angular_velocity=fm.Vector3(x=wx, y=wy, z=wz),
                pose_covariance=record.pose_covariance.reshape(36).tolist(),
                velocity_covariance=record.twist_covariance.reshape(36).tolist(),
            ), log_time=ns)
        if "tf" in ch:
            ch["tf"].log(fm.FrameTransforms(transforms=[fm.FrameTransform(
                timestamp=stamp, parent_frame_id=record.frame_id,
                child_frame_id=record.child_frame_id, translation=position, rotation=rotation,
            )]), log_time=ns)
        json_keys = ("imu", "wheel_left", "wheel_right")
        for key, _topic, _type, fields in ros_messages(record, self.topics):
            if key in json_keys and key in ch:
                ch[key].log(_json_header(fields) if "header" in fields else fields,
                            log_time=ns)

    def _client_message(self, client_id: int, channel_id: int, data: bytes) -> None:
        topic, encoding = self._client_channels.get((client_id, channel_id), ("", ""))
        if topic != self.cmd_vel_topic:
            return
        try:
            if encoding != "json":
                raise ValueError(encoding)
            msg = json.loads(data)
            v, w = float(msg["linear"]["x"]), float(msg["angular"]["z"])
            if not (math.isfinite(v) and math.isfinite(w)):
                raise ValueError((v, w))
        except (ValueError, KeyError, TypeError):
            self.cmd_vel_rejected += 1
            return
        self.cmd_vel_received += 1
        if self.on_cmd_vel is not None:
            self.on_cmd_vel(v, w)

    def _close(self) -> None:
        for channel in self._channels.values():
            with contextlib.suppress(Exception):
                channel.close()
        self._channels.clear()
        if self._server is not None:
            server, self._server = self._server, None
            self._port = server.port
            server.stop()


class _CommandListener:
    """The callbacks of a foxglove-sdk ServerListener that matter here: tracks client channels,
    forwards their messages (mixed with ``foxglove.websocket.ServerListener`` in ``_open``,
    which answers every other callback)."""

    def __init__(self, sink: FoxgloveSink) -> None:
        self.sink = sink

    def on_client_advertise(self, client: Any, channel: Any) -> None:
        self.sink._client_channels[(client.id, channel.id)] = (channel.topic, channel.encoding)

    def on_client_unadvertise(self, client: Any, client_channel_id: int) -> None:
        self.sink._client_channels.pop((client.id, client_channel_id), None)

    def on_message_data(self, client: Any, client_channel_id: int, data: bytes) -> None:
        self.sink._client_message(client.id, client_channel_id, data)
