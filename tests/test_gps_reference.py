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

IMU, ODOM, FIX = "/imu/data", "/jackal_velocity_controller/odom", "/gps/fix"
ORIGIN = (48.137154, 11.576124, 519.0)  # deg, deg, m above the ellipsoid
TURN, SHIFT = math.radians(35.0), np.array([12.0, -7.0])  # odom frame -> east, north


def _topocentric(origin: tuple[float, float, float]):
    """PROJ's transformer from (longitude, latitude, height) to its topocentric (ENU) frame at
    ``origin`` (latitude deg, longitude deg, height m)."""
    pyproj = pytest.importorskip("pyproj")  # the test extra; the alignment tests need scipy only
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


def _scipy_alignment(track: np.ndarray, ref: np.ndarray):
    """scipy's least squares over (rotation rad, translation m) from two starting angles: the
    best fit and its position RMSE, m."""
    def residual(p):
        c, s = math.cos(p[0]), math.sin(p[0])
        return (track @ np.array([[c, -s], [s, c]]).T + p[1:] - ref).ravel()

    best = min((least_squares(residual, [a, 0.0, 0.0], xtol=1e-14, ftol=1e-14, gtol=1e-14)
                for a in (0.0, math.pi)), key=lambda fit: fit.cost)
    return best, math.sqrt(2.0 * best.cost / track.shape[0])


def _at(t_fix, t, x, y):
    """(x, y) of a track at the fix times inside its span, and which fixes those are."""
    keep = (t_fix >= t[0]) & (t_fix <= t[-1])
    return np.column_stack([np.interp(t_fix[keep], t, x), np.interp(t_fix[keep], t, y)]), keep


def test_se2_alignment_is_the_least_squares_optimum():
    rng = np.random.default_rng(3)
    track = np.cumsum(rng.normal(0.0, 0.5, (300, 2)), axis=0)
    c, s = math.cos(2.5), math.sin(2.5)
    ref = track @ np.array([[c, -s], [s, c]]).T + [40.0, -3.0] + rng.normal(0.0, 0.8, (300, 2))
    best, rmse = _scipy_alignment(track, ref)
    theta, shift, moved = se2_alignment(track, ref)
    assert math.remainder(theta - best.x[0], 2 * math.pi) == pytest.approx(0.0, abs=1e-7)
    np.testing.assert_allclose(shift, best.x[1:], atol=1e-6)
    assert aligned_position_rmse(track, ref) == pytest.approx(rmse, rel=1e-9)
    assert np.sqrt(np.mean(np.sum((moved - ref) ** 2, axis=1))) == pytest.approx(rmse, rel=1e-9)


def test_a_track_that_does_not_move_still_gets_its_least_squares_residual():
    rng = np.random.default_rng(5)
    scatter = rng.normal(0.0, 2.0, (50, 2)) + np.array([100.0, 200.0])  # GPS while the robot stands
    parked = np.full((50, 2), 0.1)  # mean 0.1 - 0.1 is not exactly 0 in floating point
    want = math.sqrt(np.mean(np.sum((scatter - scatter.mean(axis=0)) ** 2, axis=1)))
    assert aligned_position_rmse(parked, scatter) == pytest.approx(want, rel=1e-9)
    assert aligned_position_rmse(scatter, np.full((50, 2), 3.0)) == pytest.approx(want, rel=1e-9)


def test_alignment_names_what_it_cannot_use():
    with pytest.raises(ValueError, match="at least 2"):
        se2_alignment(np.zeros((1, 2)), np.zeros((1, 2)))
    track = np.arange(10.0).reshape(5, 2)
    bad = track.copy()
    bad[3, 1] = math.nan
    with pytest.raises(ValueError, match=r"reference_xy: point 3 is not finite"):
        se2_alignment(track, bad)


def test_every_track_is_scored_over_the_same_fixes():
    t = np.linspace(0.0, 100.0, 101)
    en = np.column_stack([t, np.sin(t / 10.0)])
    short = (t[10:60], en[10:60] + np.array([0.0, 1.0]))  # a track over part of the run only
    out = compare_with_fixes(t, en, {"whole": (t, en), "short": short})
    assert out.compared == 50 and out.span == (10.0, 59.0)
    assert out.rmse["whole"] == pytest.approx(0.0, abs=1e-9)
    assert out.rmse["short"] == pytest.approx(0.0, abs=1e-9)  # a shift is aligned away
    np.testing.assert_allclose(out.gps_in_track_frame["short"], short[1][:50], atol=1e-9)


def test_fixes_outside_the_tracks_span_are_named():
    t = np.linspace(0.0, 10.0, 11)
    xy = np.column_stack([t, 0.0 * t])
    with pytest.raises(ValueError, match=r"0 of the 11 GPS fixes \(stamped 100.000-110.000 s\) "
                                         r"lie inside the odometry's span 0.000-10.000 s"):
        compare_with_fixes(t + 100.0, xy, {"wheel": (t, xy)})


#: how _write_bag_with_fixes writes fix i (default "fix"): a fix; status NO_FIX with NaN
#: coordinates (as receivers publish it) or with stale finite ones; no altitude (NaN); the
#: latitude and longitude as NMEA ddmm.mmmm numbers, not converted to degrees; status FIX
#: with latitude, longitude and altitude 0 (a driver filling in zeros without a fix)
FIX_KINDS = ("fix", "no-fix", "no-fix-stale", "no-altitude", "ddmm", "zeros", "multipath")
#: m north a "multipath" fix is moved
MULTIPATH = 40.0


def _write_bag_with_fixes(source: Path, dest: Path, *, kind=lambda i: "fix",
                          stamp_shift: float = 0.0, record_shift: float = 0.0) -> None:
    """The Jackal bag plus a NavSatFix topic at every 5th odometry message (10 Hz): its pose
    turned by TURN, moved by SHIFT and put on the globe at ORIGIN by PROJ; fix i written as
    ``kind(i)`` (:data:`FIX_KINDS`), stamped ``stamp_shift`` s after its odometry message."""
    pytest.importorskip("rosbags")
    from rosbags.rosbag1 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    fix_t = store.types["sensor_msgs/msg/NavSatFix"]
    status_t = store.types["sensor_msgs/msg/NavSatStatus"]
    stamp_t = store.types["builtin_interfaces/msg/Time"]
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
                what = kind(k // 5)
                north += MULTIPATH if what == "multipath" else 0.0
                lon, lat, h = to_globe.transform(east, north, 0.0, direction="INVERSE")
                assert what in FIX_KINDS
                if what == "no-fix":
                    lat = lon = h = math.nan
                elif what == "no-altitude":
                    h = math.nan
                elif what == "ddmm":
                    lat, lon = 4808.2292, 1134.5674
                elif what == "zeros":
                    lat = lon = h = 0.0
                ns_fix = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec + round(
                    stamp_shift * 1e9)
                header = dataclasses.replace(
                    msg.header, frame_id="gps",
                    stamp=stamp_t(sec=ns_fix // 10**9, nanosec=ns_fix % 10**9))
                fix = fix_t(header=header,
                            status=status_t(status=-1 if what.startswith("no-fix") else 0,
                                            service=1),
                            latitude=lat, longitude=lon, altitude=h,
                            position_covariance=np.zeros(9), position_covariance_type=0)
                writer.write(fconn, ns + round(record_shift * 1e9),
                             store.serialize_ros1(fix, "sensor_msgs/msg/NavSatFix"))
            k += 1


#: fixes the gps_bag fixture leaves without a fix or without an altitude
NO_FIX, NO_ALT = (40, 41, 42), 3


@pytest.fixture(scope="module")
def gps_bag(datasets_dir, tmp_path_factory):
    path = tmp_path_factory.mktemp("gps") / "jackal_with_gps.bag"
    _write_bag_with_fixes(datasets_dir / "rosbag" / "jackal_sim_test2.bag", path,
                          kind=lambda i: {40: "no-fix", 41: "no-fix-stale", 42: "zeros",
                                          NO_ALT: "no-altitude"}.get(i, "fix"))
    return path


def test_fixes_are_read_with_the_no_fix_messages_left_out(gps_bag):
    from fusion.io.bags import read_bag_fixes, read_bag_odometry

    fixes = read_bag_fixes(gps_bag, FIX)
    odom = read_bag_odometry(gps_bag, ODOM)
    # the no-fix messages are left out: the NaN one, the one with stale coordinates, and the
    # one at latitude and longitude 0 whatever its status (before: kept, and the printed
    # GPS RMSE went to 10^5 m)
    assert fixes.no_fix == 3 and len(fixes) == len(odom.t[::5]) - 3
    assert fixes.frame_id == "gps" and np.all(fixes.status == 0)
    assert np.all(fixes.covariance_type == 0)
    np.testing.assert_array_equal(fixes.t, np.delete(odom.t[::5], NO_FIX))
    # the coordinates written: the odometry positions turned, moved and put on the globe
    xy = np.delete(np.column_stack([odom.x, odom.y])[::5], NO_FIX, axis=0)
    c, s = math.cos(TURN), math.sin(TURN)
    east_north = xy @ np.array([[c, -s], [s, c]]).T + SHIFT
    lon, lat, h = _topocentric(ORIGIN).transform(east_north[:, 0], east_north[:, 1],
                                                 np.zeros(len(xy)), direction="INVERSE")
    np.testing.assert_array_equal(fixes.latitude, lat)
    np.testing.assert_array_equal(fixes.longitude, lon)
    # the fix without an altitude gets the first known one
    h[NO_ALT] = h[0]
    np.testing.assert_array_equal(fixes.altitude, h)


def test_replay_scores_the_tracks_against_gps(gps_bag, tmp_path, capsys):
    from fusion.evaluation.baselines import gyro_at_stops_twist
    from fusion.io.bags import read_bag_imu, read_bag_odometry

    pytest.importorskip("matplotlib")
    out, png = tmp_path / "fused.csv", tmp_path / "fused.png"
    code = main(["replay", str(gps_bag), "--imu-topic", IMU, "--odom-topic", ODOM,
                 "--gps-topic", FIX, "-o", str(out), "--plot", str(png)])
    printed = capsys.readouterr().out
    assert code == 0 and png.stat().st_size > 10_000
    assert "3 without a fix left out" in printed
    lines = {ln.split(":")[0].strip(): ln for ln in printed.splitlines()}
    score = {name: float(lines[name].split()[-2])
             for name in ("fused", "the bag's odometry", "gyro at stops")}
    assert score["the bag's odometry"] <= 0.005  # the fixes are that odometry: rounding only
    # independently: scipy's least squares between each track at the fix times inside every
    # span and the odometry positions the fixes were made from
    table = np.genfromtxt(out, delimiter=",", names=True)
    odom = read_bag_odometry(gps_bag, ODOM)
    imu = read_bag_imu(gps_bag, IMU)
    base = gyro_at_stops_twist(imu.t, imu.gyro, imu.accel, odom.t, odom.v, odom.w)
    ft = np.delete(odom.t[::5], NO_FIX)
    ref = np.delete(np.column_stack([odom.x, odom.y])[::5], NO_FIX, axis=0)
    keep = (ft >= max(table["t"][0], odom.t[0])) & (ft <= min(table["t"][-1], odom.t[-1]))
    assert f"{np.count_nonzero(keep)} compared" in printed
    for name, (t, x, y) in (("fused", (table["t"], table["x"], table["y"])),
                            ("gyro at stops", (base.t, base.poses[:, 0], base.poses[:, 1]))):
        at = np.column_stack([np.interp(ft[keep], t, x), np.interp(ft[keep], t, y)])
        assert score[name] == pytest.approx(_scipy_alignment(at, ref[keep])[1], abs=0.006), name
    # the fused heading follows the gyro, the bag's odometry its skid-steer wheels: they part
    # (measured 9.9 m), so the comparison above is not of two equal tracks
    assert score["fused"] > 1.0


def test_multipath_fixes_are_left_out_of_the_printed_score(datasets_dir, gps_bag, tmp_path,
                                                            capsys):
    # four fixes 40 m off (multipath): before, the fused track's printed RMSE rose with them;
    # now they are left out and said, and the figures are the clean bag's within rounding
    jumpy = tmp_path / "jumpy.bag"
    _write_bag_with_fixes(
        datasets_dir / "rosbag" / "jackal_sim_test2.bag", jumpy,
        kind=lambda i: {40: "no-fix", 41: "no-fix-stale", 42: "zeros", NO_ALT: "no-altitude",
                        100: "multipath", 200: "multipath", 300: "multipath",
                        400: "multipath"}.get(i, "fix"))
    scores = {}
    for name, bag in (("clean", gps_bag), ("jumpy", jumpy)):
        assert main(["replay", str(bag), "--imu-topic", IMU, "--odom-topic", ODOM,
                     "--gps-topic", FIX, "-o", str(tmp_path / f"{name}.csv")]) == 0
        printed = capsys.readouterr().out
        lines = {ln.split(":")[0].strip(): ln for ln in printed.splitlines()}
        scores[name] = {track: lines[track].split(":", 1)[1].split()
                        for track in ("fused", "the bag's odometry", "gyro at stops")}
        if name == "jumpy":
            assert "  (4 of the " in printed and " fixes left out: each jumped away" in printed
    for track, clean in scores["clean"].items():
        figure, _, every, *_ = scores["jumpy"][track]
        # the four fixes' weight is small: the figure moves by rounding at most
        assert float(figure) == pytest.approx(float(clean[0]), abs=0.02), track
        assert float(every.strip("(")) > float(clean[0]) + 0.2, track
    # the bag's odometry is what the fixes were made from: 0.00 m, and with the four 40 m
    # fixes among the 600 compared sqrt(4 / 600) * 40 = 3.3 m
    assert float(scores["jumpy"]["the bag's odometry"][2].strip("(")) == pytest.approx(3.3,
                                                                                     abs=0.1)


def test_fixes_stamped_late_are_compared_at_their_epochs_and_said(datasets_dir, gps_bag,
                                                                  tmp_path, capsys):
    # every fix stamped and recorded 1.5 s after the odometry pose it was made from (a fix
    # stamped on receipt): the bag's odometry, which the fixes are, scored metres at their
    # stamps. The lag is found where that track fits again (0.00 m, its rounding); the
    # figures at the stamps as recorded are printed beside, and the clean bag finds none.
    late = tmp_path / "late.bag"
    _write_bag_with_fixes(
        datasets_dir / "rosbag" / "jackal_sim_test2.bag", late, stamp_shift=1.5,
        record_shift=1.5,
        kind=lambda i: {40: "no-fix", 41: "no-fix-stale", 42: "zeros",
                        NO_ALT: "no-altitude"}.get(i, "fix"))
    printed = {}
    for name, bag in (("clean", gps_bag), ("late", late)):
        assert main(["replay", str(bag), "--imu-topic", IMU, "--odom-topic", ODOM,
                     "--gps-topic", FIX, "-o", str(tmp_path / f"{name}.csv")]) == 0
        printed[name] = capsys.readouterr().out
    assert "taken as stamped" not in printed["clean"]
    said = [ln for ln in printed["late"].splitlines() if "taken as stamped" in ln]
    assert len(said) == 1 and " s late (a receiver's or its driver's latency" in said[0]
    lag = float(said[0].split("taken as stamped ")[1].split(" s late")[0])
    assert lag == pytest.approx(1.5, abs=0.02)
    lines = {ln.split(":")[0].strip(): ln for ln in printed["late"].splitlines()}
    assert float(lines["the bag's odometry"].split()[-2]) <= 0.01
    recorded = float(said[0].split("the bag's odometry ")[1].split(" m")[0])
    # the Jackal drives at up to 2 m/s: 1.5 s of it along a turning path (measured 1.96 m)
    assert recorded > 0.5
    clean = {ln.split(":")[0].strip(): ln for ln in printed["clean"].splitlines()}
    for track in ("fused", "gyro at stops"):
        assert float(lines[track].split()[-2]) == pytest.approx(
            float(clean[track].split()[-2]), abs=0.05), track


def test_gps_stamped_on_another_clock_is_refused_before_anything_is_written(
        datasets_dir, tmp_path, capsys):
    # recorded 1000 s after the run as well: no fix of this run's
    shifted = tmp_path / "gps_later.bag"
    _write_bag_with_fixes(datasets_dir / "rosbag" / "jackal_sim_test2.bag", shifted,
                          stamp_shift=1000.0, record_shift=1000.0)
    out = tmp_path / "f.csv"
    assert main(["replay", str(shifted), "--imu-topic", IMU, "--odom-topic", ODOM,
                 "--gps-topic", FIX, "-o", str(out)]) != 0
    err = capsys.readouterr().err
    assert f"topic {FIX}: 0 of its 612 fixes (stamped 1047.584-1108.684 s) lie inside" in err
    assert "another clock" in err and not out.exists()


def test_gps_stamped_on_another_clock_but_recorded_with_the_run_is_moved_onto_it(
        datasets_dir, tmp_path, capsys):
    # only the header stamps 1000 s late (the receiver's clock), recorded with the run: the
    # record times show the offset against the odometry's, which is taken out, with a note
    shifted = tmp_path / "gps_stamped_later.bag"
    _write_bag_with_fixes(datasets_dir / "rosbag" / "jackal_sim_test2.bag", shifted,
                          stamp_shift=1000.0)
    same = tmp_path / "gps_on_time.bag"
    _write_bag_with_fixes(datasets_dir / "rosbag" / "jackal_sim_test2.bag", same)
    rmse = {}
    for name, bag in (("shifted", shifted), ("same", same)):
        out = tmp_path / f"{name}.csv"
        assert main(["replay", str(bag), "--imu-topic", IMU, "--odom-topic", ODOM,
                     "--gps-topic", FIX, "-o", str(out)]) == 0
        text = capsys.readouterr().out
        rmse[name] = [line for line in text.splitlines() if line.strip().startswith("fused:")]
        if name == "shifted":
            assert f"note: GPS topic {FIX}: its header stamps are +1000.000 s off" in text
    assert rmse["shifted"] == rmse["same"]


def test_a_gps_topic_of_another_type_or_without_fixes_is_named(datasets_dir, gps_bag, tmp_path,
                                                               capsys):
    from fusion.io.bags import read_bag_fixes

    jackal = datasets_dir / "rosbag" / "jackal_sim_test2.bag"
    with pytest.raises(LogFormatError, match=f"topic {ODOM} is nav_msgs/Odometry"):
        read_bag_fixes(gps_bag, ODOM)
    never = tmp_path / "never_a_fix.bag"
    _write_bag_with_fixes(jackal, never, kind=lambda i: "no-fix")
    with pytest.raises(LogFormatError, match=f"{FIX}: none of its 612 messages holds a fix"):
        read_bag_fixes(never, FIX)
    assert main(["replay", str(never), "--imu-topic", IMU, "--odom-topic", ODOM,
                 "--gps-topic", FIX, "-o", str(tmp_path / "f.csv")]) != 0
    assert "none of its 612 messages holds a fix" in capsys.readouterr().err
    ddmm = tmp_path / "ddmm.bag"
    _write_bag_with_fixes(jackal, ddmm, kind=lambda i: "ddmm" if i == 7 else "fix")
    from fusion.io.bags import read_bag_odometry

    t8 = read_bag_odometry(jackal, ODOM).t[::5][7]
    with pytest.raises(LogFormatError, match=rf"message 8 \(t = {t8:.9f} s\) has latitude "
                                             r"4808.2292, longitude 1134.5674: not degrees"):
        read_bag_fixes(ddmm, FIX)


def _drive(seconds=400.0, rate=5.0):
    """Fix times (s) and a smooth true path (m) of a robot in arcs at 1 m/s."""
    t = np.arange(0.0, seconds, 1.0 / rate)
    yaw = 0.8 * np.sin(t / 40.0) + t / 90.0
    xy = np.column_stack([np.cumsum(np.cos(yaw)), np.cumsum(np.sin(yaw))]) / rate
    return t, xy


def _turned(xy, angle):
    c, s = math.cos(angle), math.sin(angle)
    return xy @ np.array([[c, s], [-s, c]])


def test_fixes_that_jump_away_from_every_track_are_left_out_and_said():
    # 20 multipath fixes moved 50 m north in a 400 s drive with 1 m GPS noise; a good track
    # (the truth, drifting 1 % in scale) and a poor one (a heading error growing to 20 deg,
    # tens of metres off: a rule on the residual's size alone would keep the fixes it does
    # not reach). Oracle: the alignment RMSE over the clean fixes, by se2_alignment.
    rng = np.random.default_rng(3)
    t, truth = _drive()
    fixes = truth + rng.normal(0.0, 1.0, truth.shape)
    bad = np.sort(rng.choice(t.size, 20, replace=False))
    fixes[bad] += np.array([0.0, 50.0])
    good = truth * 1.01
    heading = np.radians(20.0) * t / t[-1]
    step = np.diff(truth, axis=0, prepend=truth[:1])
    poor = np.cumsum(np.column_stack([
        np.cos(heading) * step[:, 0] - np.sin(heading) * step[:, 1],
        np.sin(heading) * step[:, 0] + np.cos(heading) * step[:, 1]]), axis=0)
    out = compare_with_fixes(t, _turned(fixes, 0.7), {"good": (t, good), "poor": (t, poor)})
    assert out.outliers == 20 and out.compared == t.size
    keep = np.ones(t.size, dtype=bool)
    keep[bad] = False
    for name, track in (("good", good), ("poor", poor)):
        want = aligned_position_rmse(track[keep], _turned(fixes, 0.7)[keep])
        assert out.rmse[name] == pytest.approx(want, rel=1e-9)
        every = aligned_position_rmse(track, _turned(fixes, 0.7))
        assert out.rmse_all[name] == pytest.approx(every, rel=1e-9)
    assert out.rmse["good"] < 2.0 and out.rmse_all["good"] > 4.0  # 1.6 and 5.3 m


def test_a_track_that_goes_astray_is_not_excused_by_its_fixes():
    # clean fixes; one track leaves the path by 30 m for 20 s (a real error), the other
    # follows it: no fix is far from both, so none is left out and the error counts
    rng = np.random.default_rng(4)
    t, truth = _drive()
    fixes = truth + rng.normal(0.0, 1.0, truth.shape)
    astray = truth.copy()
    astray[(t > 200) & (t < 220), 1] += 30.0
    out = compare_with_fixes(t, fixes, {"astray": (t, astray), "on path": (t, truth)})
    assert out.outliers == 0
    assert out.rmse["astray"] == pytest.approx(aligned_position_rmse(astray, fixes), rel=1e-9)
    assert out.rmse["astray"] > 5.0
    # alone, its stretch away is the rule's to judge: 20 s is beyond the 5 s window, so the
    # departures from the local median stay small but at the stretch's ends
    alone = compare_with_fixes(t, fixes, {"astray": (t, astray)})
    assert alone.rmse["astray"] > 5.0


def _late(t, truth, lag):
    """The path ``truth`` (at ``t``) as fixes stamped ``lag`` s after each position."""
    return np.column_stack([np.interp(t - lag, t, truth[:, 0]),
                            np.interp(t - lag, t, truth[:, 1])])


def test_fixes_stamped_late_are_compared_where_they_were_taken():
    # 1 m GPS noise on a 400 s drive in arcs at 1 m/s, the fixes stamped 2 s late. Oracle:
    # se2_alignment's RMSE between each track and the fixes at their true epochs (and at
    # their stamps, for the figure kept beside).
    rng = np.random.default_rng(5)
    t, truth = _drive()
    noise = rng.normal(0.0, 1.0, truth.shape)
    fixes = _late(t, truth, 2.0) + noise
    good = truth * 1.01
    out = compare_with_fixes(t, fixes, {"truth": (t, truth), "good": (t, good)})
    # the truth alone pins it to 0.05 s; the 1 % scale of the other track reads as part of
    # a lag and pulls the joint fit a little
    assert out.lag == pytest.approx(2.0, abs=0.3)
    late = 10  # fixes (5 Hz) in 2 s: fix i was taken where the robot was at row i - 10
    for name, track in (("truth", truth), ("good", good)):
        at_epochs = aligned_position_rmse(track[:-late], fixes[late:])
        assert out.rmse[name] == pytest.approx(at_epochs, rel=0.05), name
        assert out.rmse_at_stamps[name] == pytest.approx(
            aligned_position_rmse(track, fixes), rel=1e-9)
        # measured 1.97 and 1.96 m at the stamps, 1.42 and 1.59 at the lag found (1.84 s)
        assert out.rmse_at_stamps[name] > 1.15 * out.rmse[name], name
    # without the search: the figures at the stamps, as before
    plain = compare_with_fixes(t, fixes, {"truth": (t, truth)}, find_lag=False)
    assert plain.lag == 0.0 and not plain.rmse_at_stamps
    assert plain.rmse["truth"] == pytest.approx(aligned_position_rmse(truth, fixes), rel=1e-9)


def test_no_lag_is_applied_where_the_fixes_are_on_time_or_the_path_cannot_show_it():
    rng = np.random.default_rng(6)
    t, truth = _drive()
    fixes = truth + rng.normal(0.0, 1.0, truth.shape)
    tracks = {"truth": (t, truth), "poor": (t, truth * 1.05)}
    on_time = compare_with_fixes(t, fixes, tracks)
    assert on_time.lag == 0.0 and not on_time.rmse_at_stamps
    # 0.1 s late: below LAG_MIN, the noise's doing as much as the lag's
    assert compare_with_fixes(t, _late(t, truth, 0.1) + rng.normal(0.0, 1.0, truth.shape),
                              tracks).lag == 0.0
    # a straight line at constant speed: 2 s late is a shift along it, which the alignment
    # takes out whatever the lag; none is claimed
    line = np.column_stack([t, 0.5 * t])
    straight = compare_with_fixes(t, _late(t, line, 2.0) + rng.normal(0.0, 1.0, line.shape),
                                  {"line": (t, line)})
    assert straight.lag == 0.0


def test_a_distance_scale_error_shared_by_every_track_is_no_lag():
    # the fused track, the bag's odometry and the gyro-at-stops track all drive on the
    # wheels' speed: a speed_ratio a few per cent off stretches all three alike, as a lag
    # along the path would. Under a rigid fit on-time fixes read as 1.1 s early for 3 %
    # (review); the search fits a scale too, so none is claimed, and a true lag is still
    # found through the scale error.
    t, truth = _drive(rate=1.0)
    rng = np.random.default_rng(7)
    for scale in (0.97, 1.03, 1.05):
        tracks = {"fused": (t, truth * scale), "odometry": (t, _turned(truth * scale, 0.2))}
        fixes = truth + rng.normal(0.0, 0.5, truth.shape)
        assert compare_with_fixes(t, fixes, tracks).lag == 0.0, scale
        late = _late(t, truth, 2.0) + rng.normal(0.0, 0.5, truth.shape)
        assert compare_with_fixes(t, late, tracks).lag == pytest.approx(2.0, abs=0.15), scale


def test_a_lag_beyond_the_search_is_not_applied_but_said():
    t, truth = _drive()
    rng = np.random.default_rng(8)
    fixes = _late(t, truth, 5.0) + rng.normal(0.0, 0.5, truth.shape)
    out = compare_with_fixes(t, fixes, {"truth": (t, truth)})
    assert out.lag == 0.0 and out.lag_beyond
    assert out.rmse["truth"] == pytest.approx(aligned_position_rmse(truth, fixes), rel=1e-9)
    on_time = compare_with_fixes(t, truth + rng.normal(0.0, 0.5, truth.shape),
                                 {"truth": (t, truth)})
    assert not on_time.lag_beyond


def test_a_track_sample_that_is_not_finite_between_the_fixes_keeps_the_comparison():
    # 1 Hz fixes and a track with one NaN sample between two of them: on the stamps the
    # comparison never reads it; some lags of the search would, and are passed over
    t, truth = _drive(rate=5.0)
    fix_t = t[::5]
    track = truth.copy()
    track[1001] = np.nan  # t = 200.2 s, between the fixes at 200 and 201 s
    out = compare_with_fixes(fix_t, truth[::5], {"track": (t, track)})
    assert out.rmse["track"] == pytest.approx(0.0, abs=1e-9)
