"""Publishing and bag-reading speed: records/s of each sink in fusion.sinks beside a peer
writing the same content its own way, and messages/s of fusion.io.bags.read_bag beside a bare
rosbags read loop.

- McapSink (ROS 2 CDR, written with the mcap package, 5 messages per record) vs foxglove-sdk's
  own MCAP writer with its protobuf schemas (foxglove.Odometry, FrameTransforms, JSON IMU/speeds).
- Rosbag2Sink (sqlite3 storage) vs the same messages serialised and written by rosbags
  directly (what our message building adds).
- JsonLinesSink to memory vs json.dumps of the same dicts.
- FoxgloveSink with no client connected (the cost of logging on a live server).
- read_bag (arrays, checks) on the bundled Jackal bag vs AnyReader + deserialize alone.

Run: python benchmarks/publish_throughput.py [--records N]   (needs the `ros`, `foxglove` extras)
Figures are CPU time of this process (all threads), best of a few runs.
"""

from __future__ import annotations

import argparse
import importlib.util
import io
import json
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from fusion.sinks.bag import McapSink, Rosbag2Sink
from fusion.sinks.foxglove import FoxgloveSink
from fusion.sinks.ros_messages import ros_messages
from fusion.sinks.text import JsonLinesSink
from fusion.types.fused import FusedOdometry

ROOT = Path(__file__).resolve().parents[1]
BAG = ROOT / "datasets" / "rosbag" / "jackal_sim_test2.bag"


def records(n: int) -> list[FusedOdometry]:
    rng = np.random.default_rng(0)
    cov = np.diag([0.01, 0.01, 99999, 99999, 99999, 0.003])
    out = []
    for k in range(n):
        out.append(FusedOdometry(
            t=1000.0 + 0.005 * k, x=0.001 * k, y=rng.normal(), yaw=0.001 * k, v=0.5, w=0.1,
            pose_covariance=cov, twist_covariance=cov, orientation=[1.0, 0.0, 0.0, 0.0],
            angular_velocity=rng.normal(size=3), linear_acceleration=[0.0, 0.0, 9.81],
            wheel_left_speed=0.45, wheel_right_speed=0.55))
    return out


def best_rate(fn: Callable[[], int], runs: int = 3) -> float:
    fn()  # warm-up
    best = 0.0
    for _ in range(runs):
        t0 = time.process_time()
        n = fn()
        dt = time.process_time() - t0
        if dt > 0:
            best = max(best, n / dt)
    return best


def in_tmp(make: Callable[[Path], object], recs: list[FusedOdometry]) -> Callable[[], int]:
    def run() -> int:
        d = Path(tempfile.mkdtemp())
        try:
            sink = make(d)
            with sink:
                for r in recs:
                    sink.write(r)
        finally:
            shutil.rmtree(d)
        return len(recs)
    return run


def foxglove_native_mcap(recs: list[FusedOdometry]) -> Callable[[], int]:
    import foxglove
    from foxglove import channels as fc
    from foxglove import messages as fm

    def run() -> int:
        d = Path(tempfile.mkdtemp())
        try:
            ctx = foxglove.Context()
            writer = foxglove.open_mcap(d / "peer.mcap", context=ctx)
            odom = fc.OdometryChannel("/odom", context=ctx)
            tf = fc.FrameTransformsChannel("/tf", context=ctx)
            imu = foxglove.Channel("/imu/data", context=ctx)
            wl = foxglove.Channel("/wheel_left_speed", context=ctx)
            wr = foxglove.Channel("/wheel_right_speed", context=ctx)
            for r in recs:
                ns = round(r.t * 1e9)
                stamp = fm.Timestamp(sec=ns // 10**9, nsec=ns % 10**9)
                q = r.yaw_quaternion
                pos = fm.Vector3(x=r.x, y=r.y, z=0.0)
                rot = fm.Quaternion(x=q[1], y=q[2], z=q[3], w=q[0])
                pose = fm.Pose(position=pos, orientation=rot)
                odom.log(fm.Odometry(timestamp=stamp, frame_id="odom", body_frame_id="base",
                                     pose=pose, pose_covariance=r.pose_covariance.ravel().tolist(),
                                     velocity_covariance=r.twist_covariance.ravel().tolist()),
                         log_time=ns)
                tf.log(fm.FrameTransforms(transforms=[fm.FrameTransform(
                    timestamp=stamp, parent_frame_id="odom", child_frame_id="base",
                    translation=pos, rotation=rot)]), log_time=ns)
                imu.log({"angular_velocity": r.angular_velocity.tolist()}, log_time=ns)
                wl.log({"data": r.wheel_left_speed}, log_time=ns)
                wr.log({"data": r.wheel_right_speed}, log_time=ns)
            writer.close()
        finally:
            shutil.rmtree(d)
        return len(recs)
    return run


def rosbags_message(ts, msgtype: str, value):
    """A rosbags message object from a :func:`ros_messages` dict."""
    if msgtype == "builtin_interfaces/msg/Time":
        sec, nsec = divmod(int(value), 1_000_000_000)
        return ts.types[msgtype](sec=sec, nanosec=nsec)
    kwargs = {}
    for name, (kind, detail) in ts.fielddefs[msgtype][1]:
        v = value[name]
        if kind == 2:
            kwargs[name] = rosbags_message(ts, detail, v)
        elif kind == 3:
            kwargs[name] = np.asarray(v, dtype=np.float64)
        elif kind == 4:
            kwargs[name] = [rosbags_message(ts, detail[0][1], item) for item in v]
        else:
            kwargs[name] = v
    return ts.types[msgtype](**kwargs)


def rosbags_direct(recs: list[FusedOdometry]) -> Callable[[], int]:
    """rosbags' own serialiser on messages built up front: the timed part is serialise +
    write (our sink builds the messages and serialises them with its own CDR encoder)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)

    def ros2(mt: str) -> str:
        pkg, name = mt.split("/")
        return f"{pkg}/msg/{name}"

    prebuilt = [[(topic, ros2(mt), rosbags_message(ts, ros2(mt), f))
                 for _k, topic, mt, f in ros_messages(r)] for r in recs]

    def run() -> int:
        d = Path(tempfile.mkdtemp())
        try:
            with Writer(d / "bag", version=8, storage_plugin=StoragePlugin.SQLITE3) as w:
                conns = {}
                for r, msgs in zip(recs, prebuilt):
                    ns = round(r.t * 1e9)
                    for topic, mt, msg in msgs:
                        if topic not in conns:
                            conns[topic] = w.add_connection(topic, mt, typestore=ts)
                        w.write(conns[topic], ns, ts.serialize_cdr(msg, mt))
        finally:
            shutil.rmtree(d)
        return len(recs)
    return run


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", type=int, default=3000)
    n = ap.parse_args().records
    recs = records(n)
    print(f"{n} records (5 messages each: odom, tf, imu, two wheel speeds)\n")
    rows: list[tuple[str, float, str, float]] = []

    have_ros = importlib.util.find_spec("rosbags") is not None
    have_fox = importlib.util.find_spec("foxglove") is not None
    if have_ros:
        ours = best_rate(in_tmp(lambda d: McapSink(d / "f.mcap"), recs))
        peer = best_rate(foxglove_native_mcap(recs)) if have_fox else float("nan")
        rows.append(("McapSink (ROS 2 CDR)", ours, "foxglove-sdk open_mcap (protobuf)", peer))
        ours = best_rate(in_tmp(lambda d: Rosbag2Sink(d / "b", storage="sqlite3"), recs))
        peer = best_rate(rosbags_direct(recs))
        rows.append(("Rosbag2Sink sqlite3", ours, "rosbags Writer, prebuilt messages", peer))
    else:
        print("rosbags missing: pip install 'diffbot-fusion[ros]' (bag sinks not measured)")

    def jsonl() -> int:
        with JsonLinesSink(io.StringIO(), flush=False) as s:
            for r in recs:
                s.write(r)
        return n

    dicts = [r.to_dict() for r in recs]

    def plain_json() -> int:
        buf = io.StringIO()
        for d in dicts:
            buf.write(json.dumps(d) + "\n")
        return n

    rows.append(("JsonLinesSink (memory)", best_rate(jsonl), "json.dumps of ready dicts",
                 best_rate(plain_json)))

    if have_fox:
        def live() -> int:
            with FoxgloveSink(port=0) as s:
                for r in recs:
                    s.write(r)
            return n
        rows.append(("FoxgloveSink, no client", best_rate(live), "-", float("nan")))
    else:
        print("foxglove-sdk missing: pip install 'diffbot-fusion[foxglove]'")

    print(f"{'sink':<26}{'records/s':>12}   {'peer':<36}{'records/s':>12}{'ratio':>8}")
    for name, ours, peer_name, peer in rows:
        ratio = ours / peer if peer == peer else float("nan")
        print(f"{name:<26}{ours:>12,.0f}   {peer_name:<36}{peer:>12,.0f}{ratio:>8.2f}")

    if have_ros:
        from rosbags.highlevel import AnyReader

        from fusion.io.bags import read_bag

        topics = ("/imu/data", "/jackal_velocity_controller/odom")

        def ours_read() -> int:
            log = read_bag(BAG, imu_topic=topics[0], odom_topic=topics[1])
            return len(log.imu) + len(log.odometry)

        def bare_read() -> int:
            k = 0
            with AnyReader([BAG]) as r:
                for c, _ns, raw in r.messages():
                    r.deserialize(raw, c.msgtype)
                    k += 1
            return k

        a, b = best_rate(ours_read), best_rate(bare_read)
        print(f"\nread {BAG.name}: read_bag {a:,.0f} msg/s, AnyReader + deserialize "
              f"{b:,.0f} msg/s, ratio {a / b:.2f}")


if __name__ == "__main__":
    main()
