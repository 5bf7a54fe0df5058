"""Odometry against GPS: NavSatFix topics of bags, WGS84 to east-north-up, the SE(2) alignment,
and ``fusion replay BAG --gps-topic`` (issue 11 scored a real outdoor robot's bag this way).

Oracles: PROJ (pyproj's ``cart`` + ``topocentric`` pipeline) for the geodesy, both ways;
scipy's least squares over (rotation, translation) for the alignment; for the replay, a bag
whose fixes are the bag's own odometry positions turned by 35 deg, moved, and put on the globe
by PROJ's inverse, so the bag's odometry must score 0 against them and the fused track what
scipy finds between its CSV and that odometry.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares

from fusion.cli import main
from fusion.evaluation.gps import compare_with_fixes
from fusion.evaluation.trajectory import aligned_position_rmse, se2_alignment
from fusion.geometry.geodesy import geodetic_to_enu
from fusion.io.errors import LogFormatError

pyproj = pytest.importorskip("pyproj")
pytest.importorskip("rosbags")

IMU, ODOM, FIX = "/imu/data", "/jackal_velocity_controller/odom", "/gps/fix"
ORIGIN = (48.137154, 11.576124, 519.0)  # deg, deg, m above the ellipsoid
TURN, SHIFT = math.radians(35.0), np.array([12.0, -7.0])  # odom frame -> east, north


def _topocentric(origin: tuple[float, float, float]):
    lat0, lon0, h0 = origin
    return pyproj.Transformer.from_pipeline(
        f"+proj=pipeline +step +proj=cart +ellps=WGS84 +step +proj=topocentric +ellps=WGS84 "
        f"+lat_0={lat0!r} +lon_0={lon0!r} +h_0={h0!r}")


@pytest.mark.parametrize("origin", [ORIGIN, (-33.8568, 151.2153, 5.0), (78.2232, 15.6267, 0.0),
                                    (0.0, 179.9995, -20.0)])
def test_enu_equals_projs_topocentric_frame(origin):
    rng = np.random.default_rng(7)
    # points up to ~50 km away and 1 km up or down (across the date line for the last origin)
    lat = origin[0] + rng.uniform(-0.4, 0.4, 200)
    lon = origin[1] + rng.uniform(-0.4, 0.4, 200)
    h = origin[2] + rng.uniform(-1000.0, 1000.0, 200)
    e, n, u = _topocentric(origin).transform(lon, lat, h)
    ours = geodetic_to_enu(lat, lon, h, origin)
    np.testing.assert_allclose(ours, np.column_stack([e, n, u]), rtol=0, atol=1e-6)


def test_enu_refuses_a_bad_origin():
    with pytest.raises(ValueError, match="origin"):
        geodetic_to_enu([1.0], [2.0], [0.0], (91.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="origin"):
        geodetic_to_enu([1.0], [2.0], [0.0], (math.nan, 0.0, 0.0))


def test_se2_alignment_is_the_least_squares_optimum():
    rng = np.random.default_rng(3)
    track = np.cumsum(rng.normal(0.0, 0.5, (300, 2)), axis=0)
    c, s = math.cos(2.5), math.sin(2.5)
    ref = track @ np.array([[c, -s], [s, c]]).T + [40.0, -3.0] + rng.normal(0.0, 0.8, (300, 2))

    def residual(p):
        ct, st = math.cos(p[0]), math.sin(p[0])
        return (track @ np.array([[ct, -st], [st, ct]]).T + p[1:] - ref).ravel()

    best = least_squares(residual, [0.0, 0.0, 0.0], xtol=1e-14, ftol=1e-14, gtol=1e-14)
    best_bis = least_squares(residual, [math.pi, 0.0, 0.0], xtol=1e-14, ftol=1e-14, gtol=1e-14)
    if best_bis.cost < best.cost:
        best = best_bis
    theta, shift, moved = se2_alignment(track, ref)
    assert math.remainder(theta - best.x[0], 2 * math.pi) == pytest.approx(0.0, abs=1e-7)
    np.testing.assert_allclose(shift, best.x[1:], atol=1e-6)
    rmse = math.sqrt(2.0 * best.cost / track.shape[0])
    assert aligned_position_rmse(track, ref) == pytest.approx(rmse, rel=1e-9)
    assert np.sqrt(np.mean(np.sum((moved - ref) ** 2, axis=1))) == pytest.approx(rmse, rel=1e-9)


def test_alignment_refuses_what_has_no_rotation():
    with pytest.raises(ValueError, match="does not move"):
        se2_alignment(np.ones((5, 2)), np.arange(10.0).reshape(5, 2))
    with pytest.raises(ValueError, match="at least 2"):
        se2_alignment(np.zeros((1, 2)), np.zeros((1, 2)))


def test_fixes_outside_a_tracks_span_are_named():
    t = np.linspace(0.0, 10.0, 11)
    xy = np.column_stack([t, 0.0 * t])
    with pytest.raises(ValueError, match="wheel: 0 GPS fixes inside its span"):
        compare_with_fixes(t + 100.0, xy, {"wheel": (t, xy)})


def _write_bag_with_fixes(source: Path, dest: Path, *, has_fix) -> None:
    """The Jackal bag plus a NavSatFix topic at every 5th odometry message (10 Hz): its pose
    turned by TURN, moved by SHIFT and put on the globe at ORIGIN by PROJ; a fix ``i`` for
    which ``has_fix(i)`` is False has status NO_FIX and NaN coordinates, as receivers publish
    them."""
    from rosbags.rosbag1 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    fix_t = store.types["sensor_msgs/msg/NavSatFix"]
    status_t = store.types["sensor_msgs/msg/NavSatStatus"]
    with Reader(source) as reader, Writer(dest) as writer:
        conns = {c.topic: writer.add_connection(c.topic, c.msgtype, typestore=store)
                 for c in reader.connections}
        fconn = writer.add_connection(FIX, "sensor_msgs/msg/NavSatFix", typestore=store)
        to_globe = _topocentric(ORIGIN)
        c, s = math.cos(TURN), math.sin(TURN)
        k = 0
        for conn, ns, raw in reader.messages():
            writer.write(conns[conn.topic], ns, raw)
            if conn.topic != ODOM:
                continue
            msg = store.deserialize_ros1(raw, conn.msgtype)
            if k % 5 == 0:
                p = msg.pose.pose.position
                east, north = c * p.x - s * p.y + SHIFT[0], s * p.x + c * p.y + SHIFT[1]
                lon, lat, h = to_globe.transform(east, north, 0.0, direction="INVERSE")
                good = has_fix(k // 5)
                fix = fix_t(
                    header=dataclasses.replace(msg.header, frame_id="gps"),
                    status=status_t(status=0 if good else -1, service=1),
                    latitude=lat if good else math.nan, longitude=lon if good else math.nan,
                    altitude=h if good else math.nan, position_covariance=np.zeros(9),
                    position_covariance_type=0)
                writer.write(fconn, ns, store.serialize_ros1(fix, "sensor_msgs/msg/NavSatFix"))
            k += 1


@pytest.fixture(scope="module")
def gps_bag(datasets_dir, tmp_path_factory):
    path = tmp_path_factory.mktemp("gps") / "jackal_with_gps.bag"
    _write_bag_with_fixes(datasets_dir / "rosbag" / "jackal_sim_test2.bag", path,
                          has_fix=lambda i: i != 40)
    return path


def test_fixes_are_read_with_the_no_fix_message_left_out(gps_bag):
    from fusion.io.bags import read_bag_fixes, read_bag_odometry

    fixes = read_bag_fixes(gps_bag, FIX)
    odom = read_bag_odometry(gps_bag, ODOM)
    assert fixes.no_fix == 1 and len(fixes) == len(odom.t[::5]) - 1
    assert fixes.frame_id == "gps" and np.all(fixes.status == 0)
    np.testing.assert_array_equal(fixes.t, np.delete(odom.t[::5], 40))
    # the coordinates written: the odometry positions turned, moved and put on the globe
    xy = np.delete(np.column_stack([odom.x, odom.y])[::5], 40, axis=0)
    c, s = math.cos(TURN), math.sin(TURN)
    east_north = xy @ np.array([[c, -s], [s, c]]).T + SHIFT
    lon, lat, h = _topocentric(ORIGIN).transform(east_north[:, 0], east_north[:, 1],
                                                 np.zeros(len(xy)), direction="INVERSE")
    np.testing.assert_array_equal(fixes.latitude, lat)
    np.testing.assert_array_equal(fixes.longitude, lon)
    np.testing.assert_array_equal(fixes.altitude, h)


def test_replay_scores_the_fused_track_and_the_bags_odometry_against_gps(gps_bag, tmp_path,
                                                                         capsys):
    from fusion.io.bags import read_bag_odometry

    out, png = tmp_path / "fused.csv", tmp_path / "fused.png"
    pytest.importorskip("matplotlib")
    code = main(["replay", str(gps_bag), "--imu-topic", IMU, "--odom-topic", ODOM,
                 "--gps-topic", FIX, "-o", str(out), "--plot", str(png)])
    printed = capsys.readouterr().out
    assert code == 0 and png.stat().st_size > 10_000
    assert "1 without a fix left out" in printed
    lines = {ln.split(":")[0].strip(): ln for ln in printed.splitlines()}
    own = float(lines["the bag's odometry"].split()[3])
    fused_printed = float(lines["fused"].split()[1])
    assert own <= 0.005  # the fixes are that odometry: only rounding is left
    # the fused track against the fixes, independently: scipy's least squares between the CSV
    # interpolated at the fix times and the odometry positions the fixes were made from
    table = np.genfromtxt(out, delimiter=",", names=True)
    odom = read_bag_odometry(gps_bag, ODOM)
    ft = np.delete(odom.t[::5], 40)
    ref = np.delete(np.column_stack([odom.x, odom.y])[::5], 40, axis=0)
    keep = (ft >= table["t"][0]) & (ft <= table["t"][-1])
    at = np.column_stack([np.interp(ft[keep], table["t"], table["x"]),
                          np.interp(ft[keep], table["t"], table["y"])])

    def residual(p):
        c, s = math.cos(p[0]), math.sin(p[0])
        return (at @ np.array([[c, -s], [s, c]]).T + p[1:] - ref[keep]).ravel()

    fit = least_squares(residual, [0.0, 0.0, 0.0], xtol=1e-12, ftol=1e-12)
    rmse = math.sqrt(2.0 * fit.cost / at.shape[0])
    assert fused_printed == pytest.approx(rmse, abs=0.006)
    # the fused heading follows the gyro, the bag's odometry its skid-steer wheels: they part
    # (measured 9.9 m), so the comparison above is not of two equal tracks
    assert rmse > 1.0


def test_a_gps_topic_of_another_type_or_without_fixes_is_named(datasets_dir, gps_bag, tmp_path,
                                                               capsys):
    from fusion.io.bags import read_bag_fixes

    with pytest.raises(LogFormatError, match=f"topic {ODOM} is nav_msgs/Odometry"):
        read_bag_fixes(gps_bag, ODOM)
    never = tmp_path / "never_a_fix.bag"
    _write_bag_with_fixes(datasets_dir / "rosbag" / "jackal_sim_test2.bag", never,
                          has_fix=lambda i: False)
    with pytest.raises(LogFormatError, match=f"{FIX}: none of its 612 messages holds a fix"):
        read_bag_fixes(never, FIX)
    # the command says so too, and a log directory is told --gps-topic is for bags
    assert main(["replay", str(never), "--imu-topic", IMU, "--odom-topic", ODOM,
                 "--gps-topic", FIX, "-o", str(tmp_path / "f.csv")]) != 0
    assert "none of its 612 messages holds a fix" in capsys.readouterr().err
