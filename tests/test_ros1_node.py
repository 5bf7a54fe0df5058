"""Ros1Sink against a real ROS 1 graph on loopback.

The suite's own interpreter has no rospy, so this test starts three processes under a
ROS-capable Python (Debian's /usr/bin/python3 + python3-rospy, through the venv that .ci/run
makes at .ci/ros-venv with the package installed, or $FUSION_ROS_PYTHON):

1. rosmaster on a free loopback port;
2. the node: ``Ros1Sink`` publishing a few known records in a loop and printing every
   ``/cmd_vel`` callback ``(v, w)`` as a JSON line;
3. a checker: plain rospy subscribers to the five topics that print what arrived as JSON, and
   a ``/cmd_vel`` publisher.

Without that interpreter the test skips, except under CI (``CI`` set), where it fails.
"""

from __future__ import annotations

import json
import math
import os
import queue
import socket
import subprocess
import sys
import textwrap
import threading
import time
import xmlrpc.client
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion.sinks.ros1 import RateLimiter, Ros1Sink
from fusion.types.fused import FusedOdometry

pytestmark = pytest.mark.live  # real time: run alone (pyproject's markers)

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_ROS_PYTHON = ROOT / ".ci" / "ros-venv" / "bin" / "python"
TIMEOUT = 90.0  # generous: reached only when something is broken


def ros_python() -> str:
    """The ROS-capable interpreter, or skip (fail under CI) with the reason."""
    candidate = os.environ.get("FUSION_ROS_PYTHON") or str(DEFAULT_ROS_PYTHON)
    probe = ("import rospy, rosmaster, nav_msgs.msg, tf2_msgs.msg, sensor_msgs.msg, "
             "fusion.sinks.ros1")
    reason = None
    if not Path(candidate).exists():
        reason = f"no ROS 1 interpreter at {candidate}"
    else:
        r = subprocess.run([candidate, "-c", probe], capture_output=True, text=True,
                           timeout=120, cwd=ROOT)
        if r.returncode != 0:
            reason = f"{candidate} cannot import rospy and fusion: {r.stderr.strip()[-500:]}"
    if reason:
        reason += (" (bash .ci/run creates it from Debian's python3-rospy; or set "
                   "FUSION_ROS_PYTHON)")
        if os.environ.get("CI"):
            pytest.fail(reason)
        pytest.skip(reason)
    return candidate


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def templates() -> list[FusedOdometry]:
    out = []
    for k in range(4):
        cov = np.diag([0.01 * (k + 1), 0.02, 99999.0, 99999.0, 99999.0, 0.003])
        cov[0, 5] = cov[5, 0] = 0.0004 * (k + 1)  # x-yaw: row-major index 5 and 30
        cov[0, 1] = cov[1, 0] = -0.0001  # x-y: index 1 and 6
        tw = np.diag([0.001, 99999.0, 99999.0, 99999.0, 99999.0, 0.002 * (k + 1)])
        tw[0, 5] = tw[5, 0] = 0.0003  # vx-wz: index 5 and 30
        q = Rotation.from_euler("xyz", [0.05, -0.02, 0.4 * k]).as_quat()
        out.append(FusedOdometry(
            t=1000.125 + 0.25 * k, x=0.5 * k, y=-0.25 * k, yaw=0.4 * k - 0.2,
            v=0.3 + 0.1 * k, w=-0.1 * k, pose_covariance=cov, twist_covariance=tw,
            orientation=[q[3], q[0], q[1], q[2]] if k != 1 else None,
            angular_velocity=[0.01, -0.02, -0.1 * k],
            linear_acceleration=[0.2, -0.1, 9.8] if k != 2 else None,
            wheel_left_speed=0.25 + 0.125 * k if k != 3 else None,
            wheel_right_speed=0.375 + 0.125 * k if k != 3 else None,
        ))
    return out


NODE = textwrap.dedent("""
    import json, sys, threading
    from fusion.types.fused import FusedOdometry
    from fusion.sinks import Topics
    from fusion.sinks.ros1 import Ros1Sink

    records = [FusedOdometry.from_dict(d) for d in json.loads(sys.argv[1])]
    lock = threading.Lock()

    def on_cmd_vel(v, w):
        with lock:
            print(json.dumps({"cmd_vel": [v, w]}), flush=True)

    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    sink = Ros1Sink(stamp="record", on_cmd_vel=on_cmd_vel, node_name="fusion_test_node",
                    imu_frame_id="imu_link")
    # a second sink on the same node: defaults (stamp="now"), 2 Hz of record time
    live = Ros1Sink(Topics(odom="/live/odom", tf=None, imu=None, wheel_left=None,
                           wheel_right=None), cmd_vel_topic=None, rate_hz=2.0)
    with sink, live:
        print(json.dumps({"ready": True}), flush=True)
        for i in range(4000):  # bounded: at most 200 s
            if stop.wait(0.05):
                break
            sink.write(records[i % len(records)])
            live.write(records[i % len(records)])
    print(json.dumps({"closed": sink.records_written}), flush=True)
""")

CHECKER = textwrap.dedent("""
    import json, sys, threading, time
    import genpy, rospy
    from geometry_msgs.msg import Twist
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import Imu
    from std_msgs.msg import Float32
    from tf2_msgs.msg import TFMessage

    want = json.loads(sys.argv[1])  # topic -> number of distinct messages expected

    def plain(m):
        if isinstance(m, genpy.Time):
            return [m.secs, m.nsecs]
        if isinstance(m, genpy.Message):  # Header.seq left out: it counts publications
            return {s: plain(getattr(m, s)) for s in m.__slots__ if s != "seq"}
        if isinstance(m, (list, tuple)):
            return [plain(v) for v in m]
        return m

    got = {t: {} for t in want}
    live = []  # /live/odom: [header stamp s, receipt wall time s, pose x]
    lock = threading.Lock()
    done = threading.Event()

    def check_done():
        if all(len(got[t]) >= n for t, n in want.items()) and len(live) >= 6:
            done.set()

    def callback(topic):
        def cb(msg):
            d = plain(msg)
            key = json.dumps(d, sort_keys=True)
            with lock:
                got[topic].setdefault(key, d)
                check_done()
        return cb

    def live_cb(msg):
        with lock:
            live.append([msg.header.stamp.to_sec(), time.time(), msg.pose.pose.position.x])
            check_done()

    rospy.init_node("fusion_test_checker", disable_signals=True)
    types = {"/odom": Odometry, "/tf": TFMessage, "/imu/data": Imu,
             "/wheel_left_speed": Float32, "/wheel_right_speed": Float32}
    subs = [rospy.Subscriber(t, types[t], callback(t)) for t in want]
    subs.append(rospy.Subscriber("/live/odom", Odometry, live_cb))
    cmd = rospy.Publisher("/cmd_vel", Twist, queue_size=10)
    twist = Twist()
    twist.linear.x, twist.angular.z = 0.25, -0.5
    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    reported = False
    for _ in range(2000):  # bounded: at most 200 s
        cmd.publish(twist)
        if done.is_set() and not reported:
            with lock:
                out = {t: list(v.values()) for t, v in got.items()}
                print(json.dumps({**out, "/live/odom": live}), flush=True)
            reported = True
        if stop.wait(0.1):
            break
""")


class LineReader:
    """Lines of a child's stdout on a queue, read by a thread (timeouts without select)."""

    def __init__(self, proc: subprocess.Popen, name: str) -> None:
        self.proc, self.name, self.lines = proc, name, queue.Queue()
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self) -> None:
        for line in self.proc.stdout:
            self.lines.put(line)
        self.lines.put(None)

    def next_json(self, timeout: float = TIMEOUT) -> dict:
        deadline = time.monotonic() + timeout
        while True:
            try:
                line = self.lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                raise AssertionError(f"{self.name}: no output within {timeout} s") from None
            if line is None:
                raise AssertionError(f"{self.name} exited with {self.proc.wait()}")
            line = line.strip()
            if line.startswith("{"):
                return json.loads(line)


def wait_for_master(uri: str, master: subprocess.Popen) -> None:
    deadline = time.monotonic() + TIMEOUT
    while time.monotonic() < deadline:
        if master.poll() is not None:
            raise AssertionError(f"rosmaster exited: {master.stderr.read()}")
        try:
            code, _msg, _pid = xmlrpc.client.ServerProxy(uri).getPid("/fusion_test")
            if code == 1:
                return
        except OSError:
            pass
        time.sleep(0.2)
    raise AssertionError(f"rosmaster at {uri} did not answer within {TIMEOUT} s")


def stamp_of(sec_nsec: list[int]) -> float:
    return sec_nsec[0] + sec_nsec[1] * 1e-9


def xyzw(q: dict) -> np.ndarray:
    return np.array([q["x"], q["y"], q["z"], q["w"]])


def same_rotation(q_xyzw: np.ndarray, expected_xyzw: np.ndarray) -> None:
    np.testing.assert_allclose(q_xyzw * np.sign(q_xyzw @ expected_xyzw), expected_xyzw,
                               atol=1e-12)


def by_stamp(msgs: list[dict], recs: list[FusedOdometry], header=lambda m: m["header"]):
    """Pair each received message with the template whose t equals its stamp."""
    table = {round(r.t * 1e9): r for r in recs}
    out = []
    for m in msgs:
        sec, nsec = header(m)["stamp"]
        out.append((m, table[sec * 1_000_000_000 + nsec]))
    return out


def test_ros1_node_publishes_seed_000_interface_and_hands_cmd_vel_over(tmp_path: Path) -> None:
    py = ros_python()
    recs = templates()
    port = free_port()
    uri = f"http://127.0.0.1:{port}/"
    env = {**os.environ, "ROS_MASTER_URI": uri, "ROS_IP": "127.0.0.1",
           "ROS_HOME": str(tmp_path / "ros"), "ROS_LOG_DIR": str(tmp_path / "ros" / "log"),
           "PYTHONUNBUFFERED": "1"}
    env.pop("ROS_HOSTNAME", None)
    procs: list[subprocess.Popen] = []

    def start(args: list[str], stdin=subprocess.PIPE) -> subprocess.Popen:
        p = subprocess.Popen([py, *args], env=env, cwd=tmp_path, stdin=stdin,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs.append(p)
        return p

    try:
        master = start(["-c", "import sys, rosmaster; sys.argv[0] = 'rosmaster'; "
                              "rosmaster.rosmaster_main()", "--core", "-p", str(port)],
                       stdin=subprocess.DEVNULL)
        wait_for_master(uri, master)
        node = start(["-c", NODE, json.dumps([r.to_dict() for r in recs])])
        node_out = LineReader(node, "ROS node")
        assert node_out.next_json() == {"ready": True}
        want = {"/odom": 4, "/tf": 4, "/imu/data": 4,
                "/wheel_left_speed": 3, "/wheel_right_speed": 3}  # record 3 has no speeds
        checker = start(["-c", CHECKER, json.dumps(want)])
        got = LineReader(checker, "checker").next_json()
        cmd = node_out.next_json()
        checker.stdin.close()
        node.stdin.close()
        closed = node_out.next_json(timeout=30)
        while "closed" not in closed:  # more /cmd_vel callbacks may come first
            assert closed == cmd
            closed = node_out.next_json(timeout=30)
        assert checker.wait(30) == 0, checker.stderr.read()
        assert node.wait(30) == 0, node.stderr.read()
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()

    # /cmd_vel reached the callback as (linear.x, angular.z)
    assert cmd == {"cmd_vel": [0.25, -0.5]}
    assert closed["closed"] >= 4

    live = got.pop("/live/odom")
    assert {t: len(v) for t, v in got.items()} == want  # nothing unexpected or duplicated
    # the stamp="now" sink stamps with the wall clock at publication (the records say ~1000 s)
    for stamp, received, _x in live:
        assert abs(received - stamp) < 5.0
    # ... and its 2 Hz limit, on record time (t = 1000.125 + 0.25 k, cycling), passes
    # records 0 and 2 of each cycle only
    assert {x for _s, _r, x in live} == {recs[0].x, recs[2].x}
    for m, rec in by_stamp(got["/odom"], recs):
        assert m["header"]["frame_id"] == "odom"
        assert m["child_frame_id"] == "base_footprint"
        pose = m["pose"]["pose"]
        assert [pose["position"][a] for a in "xyz"] == [rec.x, rec.y, 0.0]
        same_rotation(xyzw(pose["orientation"]), Rotation.from_euler("z", rec.yaw).as_quat())
        cov, k = m["pose"]["covariance"], recs.index(rec)
        assert len(cov) == 36
        assert cov[0] == 0.01 * (k + 1) and cov[7] == 0.02 and cov[35] == 0.003
        assert cov[5] == cov[30] == 0.0004 * (k + 1) and cov[1] == cov[6] == -0.0001
        assert cov[14] == cov[21] == cov[28] == 99999.0
        twist = m["twist"]
        assert [twist["twist"]["linear"][a] for a in "xyz"] == [rec.v, 0.0, 0.0]
        assert [twist["twist"]["angular"][a] for a in "xyz"] == [0.01, -0.02, -0.1 * k]
        tc = twist["covariance"]
        assert tc[0] == 0.001 and tc[35] == 0.002 * (k + 1) and tc[5] == tc[30] == 0.0003

    for m, rec in by_stamp(got["/tf"], recs, header=lambda m: m["transforms"][0]["header"]):
        assert len(m["transforms"]) == 1
        tf = m["transforms"][0]
        assert tf["header"]["frame_id"] == "odom" and tf["child_frame_id"] == "base_footprint"
        assert [tf["transform"]["translation"][a] for a in "xyz"] == [rec.x, rec.y, 0.0]
        same_rotation(xyzw(tf["transform"]["rotation"]),
                      Rotation.from_euler("z", rec.yaw).as_quat())

    for m, rec in by_stamp(got["/imu/data"], recs):
        k = recs.index(rec)
        assert m["header"]["frame_id"] == "imu_link"  # the sink's override
        assert math.isclose(stamp_of(m["header"]["stamp"]), rec.t, abs_tol=1e-9)
        if k == 1:  # no attitude: element 0 of the covariance is -1 (sensor_msgs/Imu)
            assert m["orientation_covariance"][0] == -1.0
        else:
            same_rotation(xyzw(m["orientation"]),
                          Rotation.from_euler("xyz", [0.05, -0.02, 0.4 * k]).as_quat())
            assert m["orientation_covariance"] == [0.0] * 9
        assert [m["angular_velocity"][a] for a in "xyz"] == [0.01, -0.02, -0.1 * k]
        if k == 2:
            assert m["linear_acceleration_covariance"][0] == -1.0
        else:
            assert [m["linear_acceleration"][a] for a in "xyz"] == [0.2, -0.1, 9.8]

    # wheel speeds (exact in float32: multiples of 1/8), m/s
    assert sorted(m["data"] for m in got["/wheel_left_speed"]) == [0.25, 0.375, 0.5]
    assert sorted(m["data"] for m in got["/wheel_right_speed"]) == [0.375, 0.5, 0.625]


def test_rate_limiter_follows_record_time() -> None:
    lim = RateLimiter(10.0)
    t = [0.0, 0.02, 0.05, 0.1, 0.13, 0.2, 0.3, 0.35, 0.41, 0.05, 0.1]
    assert [lim.due(x) for x in t] == [True, False, False, True, False, True, True, False,
                                       True, True, False]
    grid = RateLimiter(10.0)
    # a 50 Hz grid (computed as k * 0.02, with its rounding) passes every fifth sample
    assert [k for k in range(50) if grid.due(k * 0.02)] == [0, 5, 10, 15, 20, 25, 30, 35, 40,
                                                             45]
    assert all(RateLimiter(None).due(x) for x in t)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="positive"):
            RateLimiter(bad)


def test_ros1_sink_without_rospy_says_how_to_install() -> None:
    try:
        import rospy  # noqa: F401
    except ImportError:
        pass
    else:
        pytest.skip("rospy is importable here")
    with pytest.raises(ImportError, match="apt-get install python3-rospy"):
        Ros1Sink().open()
    assert "rospy" not in sys.modules  # importing fusion.sinks.ros1 did not need it


def test_ros1_sink_argument_checks() -> None:
    with pytest.raises(ValueError, match="stamp"):
        Ros1Sink(stamp="wall")
    with pytest.raises(ValueError, match="cmd_vel_topic"):
        Ros1Sink(cmd_vel_topic="cmd_vel")
    with pytest.raises(ValueError, match="child_frame_id"):
        Ros1Sink(child_frame_id="")


# -- ROS's own bag reader (Debian's python3-rosbag) as the oracle for fusion.io.bags.read_bag --

ROSBAG_DUMP = textwrap.dedent("""
    import json, sys
    import rosbag

    path, imu_topic, odom_topic = sys.argv[1:4]
    imu, odom = [], []
    with rosbag.Bag(path) as bag:
        info = bag.get_type_and_topic_info()
        topics = {t: [v.msg_type, v.message_count] for t, v in info.topics.items()}
        for topic, m, t in bag.read_messages(topics=[imu_topic, odom_topic]):
            h = m.header
            row = [h.stamp.secs, h.stamp.nsecs, t.secs, t.nsecs, h.frame_id]
            if topic == imu_topic:
                g, a, q = m.angular_velocity, m.linear_acceleration, m.orientation
                imu.append(row + [g.x, g.y, g.z, a.x, a.y, a.z, q.w, q.x, q.y, q.z])
            else:
                p, q = m.pose.pose.position, m.pose.pose.orientation
                tw = m.twist.twist
                odom.append(row + [m.child_frame_id, p.x, p.y, q.x, q.y, q.z, q.w,
                                   tw.linear.x, tw.linear.y, tw.angular.z,
                                   list(m.pose.covariance), list(m.twist.covariance)])
    print(json.dumps({"topics": topics, "imu": imu, "odom": odom}))
""")


def test_read_bag_matches_ros_own_rosbag_reader(datasets_dir) -> None:
    py = ros_python()
    probe = subprocess.run([py, "-c", "import rosbag"], capture_output=True, text=True,
                           timeout=120)
    if probe.returncode != 0:
        reason = f"{py} has no rosbag module (apt-get install python3-rosbag)"
        if os.environ.get("CI"):
            pytest.fail(reason)
        pytest.skip(reason)
    pytest.importorskip("rosbags")
    from fusion.io.bags import read_bag

    bag = datasets_dir / "rosbag" / "jackal_sim_test2.bag"
    imu_topic, odom_topic = "/imu/data", "/jackal_velocity_controller/odom"
    r = subprocess.run([py, "-c", ROSBAG_DUMP, str(bag), imu_topic, odom_topic],
                       capture_output=True, text=True, timeout=TIMEOUT)
    assert r.returncode == 0, r.stderr
    ref = json.loads(r.stdout)
    log = read_bag(bag, imu_topic=imu_topic, odom_topic=odom_topic)

    assert log.topics == {t: tuple(v) for t, v in ref["topics"].items()}
    imu = ref["imu"]
    assert len(log.imu) == len(imu) == 3061
    np.testing.assert_array_equal(log.imu.t, [row[0] + row[1] * 1e-9 for row in imu])
    np.testing.assert_array_equal(log.imu.bag_time, [row[2] + row[3] * 1e-9 for row in imu])
    assert {row[4] for row in imu} == {log.imu.frame_id}
    np.testing.assert_array_equal(log.imu.gyro, [row[5:8] for row in imu])
    np.testing.assert_array_equal(log.imu.accel, [row[8:11] for row in imu])
    # read_bag normalises the attitude; the recorded ones are unit to rounding
    np.testing.assert_allclose(log.imu.orientation, [row[11:15] for row in imu], atol=1e-15)

    odom = ref["odom"]
    assert len(log.odometry) == len(odom) == 3060
    np.testing.assert_array_equal(log.odometry.t, [row[0] + row[1] * 1e-9 for row in odom])
    assert {(row[4], row[5]) for row in odom} == {(log.odometry.frame_id,
                                                   log.odometry.child_frame_id)}
    np.testing.assert_array_equal(log.odometry.x, [row[6] for row in odom])
    np.testing.assert_array_equal(log.odometry.y, [row[7] for row in odom])
    yaw = Rotation.from_quat([row[8:12] for row in odom]).as_euler("ZYX")[:, 0]
    np.testing.assert_allclose(log.odometry.yaw, yaw, atol=1e-12)
    np.testing.assert_array_equal(log.odometry.v, [row[12] for row in odom])
    np.testing.assert_array_equal(log.odometry.vy, [row[13] for row in odom])
    np.testing.assert_array_equal(log.odometry.w, [row[14] for row in odom])
    np.testing.assert_array_equal(log.odometry.pose_covariance, [row[15] for row in odom])
    np.testing.assert_array_equal(log.odometry.twist_covariance, [row[16] for row in odom])


def test_ros1_sink_without_a_master_says_so(tmp_path: Path) -> None:
    py = ros_python()
    port = free_port()  # nothing listens there
    env = {**os.environ, "ROS_MASTER_URI": f"http://127.0.0.1:{port}/",
           "ROS_IP": "127.0.0.1", "ROS_HOME": str(tmp_path)}
    script = ("from fusion.sinks.ros1 import Ros1Sink\n"
              "try:\n"
              "    Ros1Sink().open()\n"
              "except ConnectionError as exc:\n"
              "    print('ConnectionError:', exc)\n")
    r = subprocess.run([py, "-c", script], env=env, capture_output=True, text=True,
                       timeout=TIMEOUT)
    assert r.returncode == 0, r.stderr
    assert f"ConnectionError: no ROS master at http://127.0.0.1:{port}/" in r.stdout
