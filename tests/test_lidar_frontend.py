"""The LiDAR frontend on synthetic sweeps: rows, statuses, deskew, and the degeneracy spectrum."""

from __future__ import annotations

import math
from functools import cache

import numpy as np
import pytest

from frontdiag import metrics
from frontdiag.lidar import synth
from frontdiag.lidar.deskew import deskew, sweep_displacement
from frontdiag.lidar.frontend import EXTRA_COLUMNS, LidarFrontend, LidarParams
from frontdiag.lidar.se3 import inv, rotation_angle_deg, se3_exp, se3_exp_batch
from frontdiag.lidar.spectrum import describe_direction
from frontdiag.records import LidarScan

T0 = 1_000_000_000_000
PERIOD_NS = 100_000_000
TWIST = np.array([0.0, 0.0, 0.05, 1.5, 0.0, 0.0])  # 1.5 m/s forward, turning slowly


def as_scan(xyz: np.ndarray, times: np.ndarray | None, k: int, planar: bool = False) -> LidarScan:
    keep = np.isfinite(xyz).all(axis=-1)
    return LidarScan(index=k, t_ns=T0 + k * PERIOD_NS, log_ns=T0 + k * PERIOD_NS, topic="/points",
                     xyz=xyz[keep], time_rel_s=None if times is None else times[keep],
                     planar=planar, n_raw=int(keep.size))


@cache
def sequence(scene_name: str, n: int = 8) -> tuple[tuple[LidarScan, ...], tuple[np.ndarray, ...]]:
    """Scans of a sensor driving through a scene, and the true pose at each scan's mid-sweep."""
    scene = {"corridor": synth.corridor_scene(), "hall": synth.hall_scene()}[scene_name]
    scans, truth = [], []
    for k in range(n):
        pose = se3_exp(TWIST * 0.1 * k)
        xyz, t = synth.spinning_scan(scene, beams=32, columns=1024, pose0=pose, twist=TWIST,
                                     seed=k)
        scans.append(as_scan(xyz, t, k))
        truth.append(pose @ se3_exp(TWIST * 0.05))
    return tuple(scans), tuple(truth)


def run(scene_name: str, params: LidarParams | None = None) -> tuple[list[dict], LidarFrontend]:
    fe = LidarFrontend(params or LidarParams())
    scans, _ = sequence(scene_name)
    return [fe.process(s) for s in scans], fe


def test_row_has_every_lidar_column_and_the_declared_extras() -> None:
    rows, _ = run("hall")
    expected = set(metrics.LIDAR_COLUMNS) - {"frame", "t_ns", "sensor", "topic"}
    for row in rows:
        assert expected <= set(row)
        assert set(row) - expected <= set(EXTRA_COLUMNS)
    for name in EXTRA_COLUMNS:
        assert metrics.METRICS[name].sensor == "lidar"
    assert rows[0]["status"] == "first_scan"
    assert [r["status"] for r in rows[1:]] == ["ok"] * (len(rows) - 1)


def test_hall_is_tracked_and_healthy() -> None:
    rows, fe = run("hall")
    _, truth = sequence("hall")
    rel_true = inv(truth[0]) @ truth[-1]
    err = inv(rel_true) @ fe.pose
    assert np.linalg.norm(err[:3, 3]) < 0.05
    assert rotation_angle_deg(err) < 0.5
    for row in rows[2:]:
        assert row["lidar_prior"] == "constant_velocity"
        assert row["icp_fitness"] > 0.8
        assert row["lidar_eig_min"] > 500  # hundreds of points' worth along the weakest direction
        assert row["lidar_cond"] < 100


def test_corridor_is_flagged_and_its_axis_named() -> None:
    rows, _ = run("corridor")
    for row in rows[2:]:
        # the reference signature: an excellent fit ...
        assert row["icp_fitness"] > 0.8
        assert row["icp_rmse_m"] < 0.05
        # ... and no information along the corridor
        assert row["lidar_eig_min"] < 50
        assert row["lidar_cond"] > 900
        assert row["lidar_weak_dir"] == "translation along x (forward)"


def test_spectrum_separates_corridor_from_hall_by_two_orders_of_magnitude() -> None:
    corridor, _ = run("corridor")
    hall, _ = run("hall")
    c = np.median([r["lidar_eig_min"] for r in corridor[2:]])
    h = np.median([r["lidar_eig_min"] for r in hall[2:]])
    assert h / c > 100


def test_deskew_displacement_of_the_worked_example() -> None:
    # 1.5 m/s straight ahead over a 100 ms sweep: the first and last points are 15 cm apart
    pts = np.random.default_rng(0).uniform(-10, 10, size=(500, 3))
    assert sweep_displacement(pts, 0.1, np.array([0, 0, 0, 1.5, 0, 0])) == pytest.approx(0.15)


def test_deskew_matches_the_exact_exponential_per_point() -> None:
    rng = np.random.default_rng(1)
    p = rng.uniform(-30, 30, size=(2000, 3))
    s = rng.uniform(0.0, 0.1, size=2000)
    xi = np.array([0.2, -0.1, 1.0, 1.5, 0.3, 0.0])
    out, _ = deskew(p, s, xi, ref_s=0.05)
    T = se3_exp_batch((s - 0.05)[:, None] * xi[None, :])
    exact = np.einsum("nij,nj->ni", T[:, :3, :3], p) + T[:, :3, 3]
    assert np.abs(out - exact).max() < 0.005  # the 1024-bin bound: 5 mm at 100 m, 1 rad/s


def test_frontend_reports_the_sweep_skew_of_a_moving_sensor() -> None:
    scene = synth.hall_scene()
    twist = np.array([0.0, 0.0, 0.0, 1.5, 0.0, 0.0])
    fe = LidarFrontend()
    rows = []
    for k in range(5):
        xyz, t = synth.spinning_scan(scene, beams=32, columns=1024,
                                     pose0=se3_exp(twist * 0.1 * k), twist=twist, seed=k)
        rows.append(fe.process(as_scan(xyz, t, k)))
    assert rows[0]["deskew_m"] == 0.0  # nothing known, nothing applied
    assert math.isnan(rows[1]["deskew_m"])  # no motion prior yet
    for row in rows[2:]:
        # span of the sweep's times is 1023/1024 of 100 ms
        assert row["deskew_m"] == pytest.approx(0.15, abs=0.02)


def test_hard_scans_give_a_status_not_an_exception() -> None:
    fe = LidarFrontend()
    empty = LidarScan(index=0, t_ns=T0, log_ns=T0, topic="/p", xyz=np.zeros((0, 3)),
                      time_rel_s=None)
    few = LidarScan(index=1, t_ns=T0 + PERIOD_NS, log_ns=0, topic="/p",
                    xyz=np.random.default_rng(0).normal(size=(5, 3)) * 5, time_rel_s=None)
    nan = LidarScan(index=2, t_ns=T0 + 2 * PERIOD_NS, log_ns=0, topic="/p",
                    xyz=np.full((50, 3), np.nan), time_rel_s=np.zeros(50))
    for scan in (empty, few, nan):
        row = fe.process(scan)
        assert row["status"] == "too_few_points"
        assert row["ms_total"] >= 0


def test_timing_goes_through_the_injected_clock() -> None:
    ticks = iter(np.arange(0.0, 10.0, 0.001))
    fe = LidarFrontend(clock=lambda: float(next(ticks)))
    scans, _ = sequence("hall")
    fe.process(scans[0])
    row = fe.process(scans[1])
    assert row["ms_lidar_preprocess"] == pytest.approx(1.0)
    assert row["ms_lidar_register"] == pytest.approx(1.0)
    assert row["ms_total"] == pytest.approx(row["ms_lidar_preprocess"] + row["ms_lidar_register"]
                                            + row["ms_lidar_map"])


def test_deterministic() -> None:
    a, _ = run("hall")
    b, _ = run("hall")
    for ra, rb in zip(a, b, strict=True):
        for key, va in ra.items():
            if not key.startswith("ms_"):
                assert va == rb[key] or (va != va and rb[key] != rb[key]), key


def test_odometry_is_the_prior_when_it_covers_the_scans() -> None:
    scans, truth = sequence("hall")
    fe = LidarFrontend()
    for k in range(-1, 11):  # wheel odometry at 10 Hz, mid-sweep instants, covering every scan
        fe.add_odometry(T0 + k * PERIOD_NS + PERIOD_NS // 2, se3_exp(TWIST * 0.1 * k))
    rows = [fe.process(s) for s in scans]
    assert all(r["lidar_prior"] == "odometry" for r in rows[1:])
    assert rows[1]["deskew_m"] == pytest.approx(0.15 + 0.05 * 0.1 * 10, abs=0.05)
    err = inv(inv(truth[0]) @ truth[-1]) @ fe.pose
    assert np.linalg.norm(err[:3, 3]) < 0.05


def planar_rows(scene: list, twist: np.ndarray, n: int = 6) -> tuple[list[dict], LidarFrontend]:
    fe = LidarFrontend()
    rows = []
    for k in range(n):
        f = synth.planar_scan(scene, pose0=se3_exp(twist * 0.1 * k), twist=twist, seed=k)
        ang = f["angle_min"] + f["angle_increment"] * np.arange(len(f["ranges"]))
        r = f["ranges"].astype(np.float64)
        hit = np.isfinite(r)
        xyz = np.full((len(r), 3), np.nan)
        xyz[hit] = np.c_[r[hit] * np.cos(ang[hit]), r[hit] * np.sin(ang[hit]), np.zeros(hit.sum())]
        rows.append(fe.process(as_scan(xyz, f["time_increment"] * np.arange(len(r)), k,
                                       planar=True)))
    return rows, fe


def test_planar_scans_register_in_three_dof() -> None:
    rows, fe = planar_rows(synth.hall_scene(), np.array([0.0, 0.0, 0.2, 1.0, 0.0, 0.0]))
    assert [r["status"] for r in rows] == ["first_scan"] + ["ok"] * 5
    pose = fe.pose
    assert pose[2, 3] == 0.0 and pose[2, 2] == 1.0  # z, roll and pitch stay out of a 2D scan
    assert abs(pose[0, 3] - 0.5) < 0.1
    for row in rows[1:]:
        assert row["lidar_eig_min"] > 500 and row["lidar_cond"] < 100


def test_planar_corridor_is_flagged_with_its_axis() -> None:
    rows, fe = planar_rows(synth.corridor_scene(), np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0]))
    for row in rows[1:]:
        assert row["icp_fitness"] > 0.95 and row["icp_rmse_m"] < 0.02  # a perfect fit ...
        assert row["lidar_eig_min"] < 50 and row["lidar_cond"] > 900   # ... constraining nothing
        assert row["lidar_weak_dir"] == "translation along x (forward)"
    assert abs(fe.pose[0, 3]) < 0.1  # and the pose did not follow the 0.5 m drive along it


@pytest.mark.parametrize(("vec", "planar", "words"), [
    ([0, 0, 0, 1, 0, 0], False, "translation along x (forward)"),
    ([0, 0, 0, 0, -1, 0], False, "translation along y (left)"),
    ([0, 0, 1, 0, 0, 0], False, "yaw (rotation about z)"),
    ([1, 0, 0, 0, 0, 0.1], False, "roll (rotation about x)"),
    ([0, 0, 0, 0.8, 0.6, 0], False, "translation along (+0.80x +0.60y), mostly x (forward)"),
    ([0.6, 0, 0, 0, 0.8, 0], False,
     "translation along y (left) coupled with roll (rotation about x)"),
    ([1, 0, 0], True, "yaw (rotation about z)"),
    ([0, 0, 1], True, "translation along y (left)"),
])
def test_weak_direction_in_words(vec: list[float], planar: bool, words: str) -> None:
    assert describe_direction(np.array(vec, float), planar) == words


def test_odometry_history_does_not_grow_with_the_recording() -> None:
    scans, _ = sequence("hall")
    fe = LidarFrontend()
    for k in range(-1, 200):  # 20 s of odometry at 10 Hz, arriving ahead of the scans
        fe.add_odometry(T0 + k * PERIOD_NS + PERIOD_NS // 2, se3_exp(TWIST * 0.1 * k))
    for s in scans:
        fe.process(s)
    assert len(fe._odom_t) < 200 - len(scans) + 5


def test_a_scan_that_matches_nothing_is_low_overlap_and_keeps_the_prediction() -> None:
    scans, _ = sequence("hall")
    fe = LidarFrontend()
    for s in scans[:4]:
        fe.process(s)
    before = fe.pose
    far = synth.spinning_scan([synth.room((-3, -3, -1), (3, 3, 2))], beams=32, columns=1024,
                              seed=9)[0]
    far = far + np.array([0.0, 0.0, 30.0])  # a small room floating above the hall
    row = fe.process(as_scan(far, None, 4))
    assert row["status"] == "low_overlap"
    assert row["icp_fitness"] < 0.3
    step = inv(before) @ fe.pose
    # the prediction: this scan has no per-point time, so its pose is at its stamp, 50 ms after
    # the previous pose (taken at mid-sweep), and at 1.5 m/s the prior moves it 7.5 cm
    assert np.linalg.norm(step[:3, 3]) == pytest.approx(0.075, abs=0.01)


def test_tracking_recovers_when_the_second_scan_matches_nothing() -> None:
    scans, truth = sequence("hall")
    far = synth.spinning_scan([synth.room((-3, -3, -1), (3, 3, 2))], beams=32, columns=1024,
                              seed=9)[0] + np.array([0.0, 0.0, 30.0])
    fe = LidarFrontend()
    rows = [fe.process(scans[0]), fe.process(as_scan(far, None, 1))]
    rows += [fe.process(s) for s in scans[2:]]
    assert [r["status"] for r in rows[:2]] == ["first_scan", "low_overlap"]
    assert all(r["status"] == "ok" for r in rows[2:])
    err = inv(inv(truth[0]) @ truth[-1]) @ fe.pose
    assert np.linalg.norm(err[:3, 3]) < 0.05


def test_reset_starts_a_new_map_in_the_new_place() -> None:
    """After a gap the sensor may be elsewhere: the next scan starts a fresh map, and what
    follows is measured against that place (a corridor reads degenerate, not the hall)."""
    hall, _ = sequence("hall")
    corridor, _ = sequence("corridor")
    fe = LidarFrontend()
    rows = [fe.process(s) for s in hall[:4]]
    assert rows[0]["status"] == "first_scan" and rows[-1]["status"] == "ok"
    fe.reset()
    after = [fe.process(s) for s in corridor[4:]]
    assert after[0]["status"] == "first_scan"
    assert [r["status"] for r in after[1:]] == ["ok"] * 3
    assert min(r["lidar_cond"] for r in after[1:]) > 900


def test_a_mounted_sensors_prior_is_its_own_motion_not_the_bases() -> None:
    """Odometry gives the base's poses; with the sensor mounted off the base's origin and
    turned (X = base ← sensor), the prior is X⁻¹ Δ X: a turn of the base on the spot moves a
    sensor 1 m ahead of it sideways, which the base's own Δ does not."""
    fe = LidarFrontend()
    yaw = np.array([0.0, 0.0, 0.3, 0.0, 0.0, 0.0])  # rotation first, then translation
    for k in range(3):  # the base turns on the spot, 0.3 rad a step
        fe.add_odometry(T0 + k * PERIOD_NS, se3_exp(yaw * k))
    fe._poses = [(T0, np.eye(4))]
    base_delta, _, src = fe._prior(T0 + PERIOD_NS)
    assert src == "odometry" and np.linalg.norm(base_delta[:3, 3]) < 1e-12
    X = np.eye(4)  # 1 m ahead of the base, turned 0.2 rad about its vertical
    X[:3, :3] = se3_exp(np.array([0.0, 0.0, 0.2, 0.0, 0.0, 0.0]))[:3, :3]
    X[0, 3] = 1.0
    fe.set_mount(X)
    delta, twist, src = fe._prior(T0 + PERIOD_NS)
    assert src == "odometry"
    np.testing.assert_allclose(delta, inv(X) @ base_delta @ X, atol=1e-12)
    assert twist[2] == pytest.approx(3.0)  # the yaw rate is the base's: 0.3 rad in 0.1 s
    # the sensor 1 m ahead swings through a chord of 2 sin(0.15) m
    assert np.linalg.norm(delta[:3, 3]) == pytest.approx(2 * np.sin(0.15), rel=1e-9)
