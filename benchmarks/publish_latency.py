"""Live publishing latency on loopback: from ``sink.write(record)`` to a subscriber holding the
decoded /odom message, p50/p99, beside a peer publishing the same message its plain way.

- Foxglove: FoxgloveSink vs a foxglove-sdk OdometryChannel logging a ready-made message; the
  client is a websockets connection in this process decoding the protobuf payload.
- ROS 1 (needs the ROS interpreter that .ci/run makes, or FUSION_ROS_PYTHON): rosmaster, a
  publisher process and a rospy subscriber process on loopback; Ros1Sink vs a plain
  rospy.Publisher of a prebuilt nav_msgs/Odometry.

Stamps are ``time.time()`` in the publishing process, read back by the receiver on the same
host clock. Run: python benchmarks/publish_latency.py [--messages N] [--rate HZ]
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import json
import os
import socket
import subprocess
import sys
import tempfile
import textwrap
import threading
import time
import xmlrpc.client
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: the default covariance of a FusedOdometry, so the peers send the same content
COV = np.diag([0.0, 0.0, 99999.0, 99999.0, 99999.0, 0.0]).ravel().tolist()


def summary(name: str, lat_s: list[float]) -> str:
    a = np.asarray(lat_s) * 1e3
    return (f"{name:<40} n={a.size:5d}  p50 {np.percentile(a, 50):7.3f} ms  "
            f"p99 {np.percentile(a, 99):7.3f} ms  max {a.max():7.3f} ms")


# -- Foxglove ---------------------------------------------------------------------------------


def foxglove_latency(n: int, rate: float, plain: bool) -> list[float]:
    import foxglove
    import websockets
    from foxglove import channels as fc
    from foxglove import messages as fm
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    from fusion.sinks.foxglove import FoxgloveSink
    from fusion.sinks.ros_messages import Topics
    from fusion.types.fused import FusedOdometry

    if plain:
        ctx = foxglove.Context()
        server = foxglove.start_server(port=0, context=ctx)
        chan = fc.OdometryChannel("/odom", context=ctx)
        port = server.port

        def publish(k: int) -> None:
            now = time.time()
            ns = int(now * 1e9)
            chan.log(fm.Odometry(
                timestamp=fm.Timestamp(sec=ns // 10**9, nsec=ns % 10**9), frame_id="odom",
                body_frame_id="base_footprint",
                pose=fm.Pose(position=fm.Vector3(x=0.01 * k, y=0.0, z=0.0),
                             orientation=fm.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
                linear_velocity=fm.Vector3(x=0.5, y=0.0, z=0.0),
                angular_velocity=fm.Vector3(x=0.0, y=0.0, z=0.0),
                pose_covariance=COV, velocity_covariance=COV), log_time=ns)

        def stop() -> None:
            server.stop()
    else:
        sink = FoxgloveSink(port=0, topics=Topics(tf=None, imu=None, wheel_left=None,
                                                  wheel_right=None))
        sink.open()
        port = sink.port

        def publish(k: int) -> None:
            sink.write(FusedOdometry(t=time.time(), x=0.01 * k, y=0.0, yaw=0.0, v=0.5, w=0.0))

        stop = sink.close

    got: list[float] = []
    done = threading.Event()
    ready = threading.Event()

    async def client() -> None:
        async with websockets.connect(f"ws://127.0.0.1:{port}",
                                      subprotocols=["foxglove.sdk.v1"]) as ws:
            cls = None
            while cls is None:
                msg = json.loads(await ws.recv())
                if msg["op"] == "advertise":
                    ch = msg["channels"][0]
                    fds = descriptor_pb2.FileDescriptorSet.FromString(
                        base64.b64decode(ch["schema"]))
                    pool = descriptor_pool.DescriptorPool()
                    for fd in fds.file:
                        pool.Add(fd)
                    cls = message_factory.GetMessageClass(
                        pool.FindMessageTypeByName(ch["schemaName"]))
            await ws.send(json.dumps({"op": "subscribe",
                                      "subscriptions": [{"id": 1, "channelId": ch["id"]}]}))
            ready.set()
            while len(got) < n:
                frame = await asyncio.wait_for(ws.recv(), 30)
                if isinstance(frame, bytes) and frame[0] == 1:
                    odom = cls.FromString(frame[13:])
                    stamp = odom.timestamp.seconds + odom.timestamp.nanos * 1e-9
                    got.append(time.time() - stamp)
            done.set()

    th = threading.Thread(target=lambda: asyncio.run(client()), daemon=True)
    th.start()
    ready.wait(30)
    time.sleep(0.5)  # let the subscription reach the server (the protocol has no ack)
    k = 0
    while not done.is_set() and k < 3 * n:
        publish(k)
        k += 1
        time.sleep(1.0 / rate)
    th.join(30)
    stop()
    return got[-n:]


# -- ROS 1 ------------------------------------------------------------------------------------

ROS_PUBLISHER = textwrap.dedent("""
    import sys, time
    n, rate, plain = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3] == "plain"
    import rospy
    from nav_msgs.msg import Odometry
    from fusion.types.fused import FusedOdometry
    from fusion.sinks import Topics
    from fusion.sinks.ros1 import Ros1Sink
    topics = Topics(tf=None, imu=None, wheel_left=None, wheel_right=None)
    if plain:
        rospy.init_node("bench_pub", disable_signals=True)
        pub = rospy.Publisher("/odom", Odometry, queue_size=10)
    else:
        sink = Ros1Sink(topics, stamp="record", cmd_vel_topic=None, node_name="bench_pub")
        sink.open()
    time.sleep(2.0)  # subscriber connects
    for k in range(n):
        if plain:
            m = Odometry()
            m.header.frame_id, m.child_frame_id = "odom", "base_footprint"
            m.pose.pose.position.x, m.pose.pose.orientation.w = 0.01 * k, 1.0
            m.twist.twist.linear.x = 0.5
            m.pose.covariance = m.twist.covariance = [0.0, 0, 0, 0, 0, 0, 0, 0] + [
                99999.0 if i in (6, 13, 20) else 0.0 for i in range(28)]
            m.header.stamp = rospy.Time.from_sec(time.time())
            pub.publish(m)
        else:
            sink.write(FusedOdometry(t=time.time(), x=0.01 * k, y=0, yaw=0, v=0.5, w=0))
        time.sleep(1.0 / rate)
    time.sleep(1.0)
""")

ROS_SUBSCRIBER = textwrap.dedent("""
    import json, sys, time, threading
    import rospy
    from nav_msgs.msg import Odometry
    n = int(sys.argv[1])
    lat, done = [], threading.Event()
    def cb(m):
        lat.append(time.time() - m.header.stamp.to_sec())
        if len(lat) >= n:
            done.set()
    rospy.init_node("bench_sub", disable_signals=True)
    rospy.Subscriber("/odom", Odometry, cb, tcp_nodelay=True)
    done.wait(60)
    print(json.dumps(lat))
""")


def ros_python() -> str | None:
    candidate = os.environ.get("FUSION_ROS_PYTHON") or str(ROOT / ".ci/ros-venv/bin/python")
    if not Path(candidate).exists():
        return None
    ok = subprocess.run([candidate, "-c", "import rospy, fusion.sinks.ros1"], capture_output=True)
    return candidate if ok.returncode == 0 else None


def ros1_latency(py: str, n: int, rate: float, plain: bool) -> list[float]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    tmp = tempfile.mkdtemp()
    uri = f"http://127.0.0.1:{port}/"
    env = {**os.environ, "ROS_MASTER_URI": uri, "ROS_IP": "127.0.0.1", "ROS_HOME": tmp}
    procs = []
    try:
        procs.append(subprocess.Popen(
            [py, "-c", "import sys, rosmaster; sys.argv[0] = 'rosmaster'; "
             "rosmaster.rosmaster_main()", "--core", "-p", str(port)], env=env,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        for _ in range(100):
            try:
                xmlrpc.client.ServerProxy(uri).getPid("/bench")
                break
            except OSError:
                time.sleep(0.1)
        sub = subprocess.Popen([py, "-c", ROS_SUBSCRIBER, str(n)], env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        procs.append(sub)
        procs.append(subprocess.Popen(
            [py, "-c", ROS_PUBLISHER, str(n), str(rate), "plain" if plain else "sink"],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        out, _ = sub.communicate(timeout=180)
        return json.loads(out) if out.strip() else []
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.terminate()
                p.wait(10)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--messages", type=int, default=500)
    ap.add_argument("--rate", type=float, default=100.0, help="publish rate, Hz")
    args = ap.parse_args()
    print(f"{args.messages} /odom messages at {args.rate:g} Hz on loopback\n")
    try:
        ours = foxglove_latency(args.messages, args.rate, plain=False)
        peer = foxglove_latency(args.messages, args.rate, plain=True)
        print(summary("FoxgloveSink -> websockets client", ours))
        print(summary("foxglove-sdk OdometryChannel (peer)", peer))
        print(f"{'p50 ratio ours/peer':<40} {np.median(ours) / np.median(peer):.2f}\n")
    except ImportError as exc:
        print(f"Foxglove not measured: {exc}")
    py = ros_python()
    if py is None:
        print("ROS 1 not measured: no ROS interpreter (bash .ci/run makes .ci/ros-venv, or set "
              "FUSION_ROS_PYTHON)")
        return
    ours = ros1_latency(py, args.messages, args.rate, plain=False)
    peer = ros1_latency(py, args.messages, args.rate, plain=True)
    if not ours or not peer:
        print("ROS 1: no messages received", file=sys.stderr)
        return
    print(summary("Ros1Sink -> rospy subscriber", ours))
    print(summary("rospy.Publisher, prebuilt msg (peer)", peer))
    print(f"{'p50 ratio ours/peer':<40} {np.median(ours) / np.median(peer):.2f}")


if __name__ == "__main__":
    main()
