"""Commands a new user runs: rules in their own namespace added to the shipped ones, typos that
get a suggestion, explain on the wrong thing, eval as an accuracy gate, a config file for the
frontend, --debug after the subcommand, shell completion, and the typed Python API."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pandas as pd
import pytest
from recording_factory import write_recording
from test_rules_files import RULE

import frontdiag
from frontdiag.cli import hoist_root_flags, main
from frontdiag.config import load_config
from frontdiag.errors import ConfigError
from frontdiag.scoring import ConditionScore
from frontdiag.verdicts import load_ruleset


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(args)
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def _rules(tmp_path: Path, rule_id: str = "MY-001", metric: str = "entropy_norm") -> Path:
    d = tmp_path / "my_rules"
    d.mkdir(parents=True, exist_ok=True)
    text = RULE.format(condition="feature_clustering", metric=metric, op="<")
    (d / "mine.toml").write_text(text.replace('"FD-TST-001"', f'"{rule_id}"'))
    return d


def test_user_rules_take_their_own_namespace_and_add_to_the_shipped(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = _rules(tmp_path)
    shipped = len(load_ruleset().rules)
    both = load_ruleset(extra_dirs=[d])
    assert len(both.rules) == shipped + 1 and both.get("MY-001").area == "mine"
    code, out, _ = run(["rules", "list", "--rules", str(d), "--json"], capsys)
    ids = [r["id"] for r in json.loads(out)["rules"]]
    assert code == 0 and "MY-001" in ids and "FD-PLN-001" in ids
    code, out, _ = run(["rules", "list", "--rules", str(d), "--no-default-rules", "--json"],
                       capsys)
    assert [r["id"] for r in json.loads(out)["rules"]] == ["MY-001"]
    # a shipped ID cannot be redefined by an added directory
    clash = _rules(tmp_path / "b", rule_id="FD-PLN-001")
    with pytest.raises(Exception, match="already defined"):
        load_ruleset(extra_dirs=[clash])


def test_a_metric_typo_gets_a_suggestion(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    d = _rules(tmp_path, metric="entropy_nrom")
    code, _, err = run(["rules", "check", str(d)], capsys)
    assert code == 2 and "did you mean 'entropy_norm'" in err
    code, _, err = run(["rules", "explain", "FD-PLN-01"], capsys)
    assert code == 2 and "did you mean 'FD-PLN-001'" in err


def test_debug_is_accepted_after_the_subcommand(capsys: pytest.CaptureFixture[str]) -> None:
    assert hoist_root_flags(["rules", "list", "--debug"]) == ["--debug", "rules", "list"]
    assert hoist_root_flags(["a", "--", "--debug"]) == ["a", "--", "--debug"]
    code, out, _ = run(["rules", "list", "--debug"], capsys)
    assert code == 0 and "FD-PLN-001" in out


def test_shell_completion_and_choices_in_help(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(["--help"], capsys)
    assert code == 0 and "--install-completion" in out
    code, out, _ = run(["analyze", "--help"], capsys)
    assert "[warn|fail|never]" in out and "[parquet|csv]" in out


def test_flags_in_help_take_no_value(capsys: pytest.CaptureFixture[str]) -> None:
    # a flag's row shows no value type: "--json <bool>" reads as if it took true or false
    for cmd in (["--help"], ["analyze", "--help"], ["loops", "--help"], ["budget", "--help"]):
        code, out, _ = run(cmd, capsys)
        assert code == 0 and "--" in out
        assert "<bool>" not in out, cmd
    code, out, _ = run(["analyze", "--help"], capsys)
    assert "<int>" in out  # options that take a value keep their type


def test_explain_on_a_recording_says_to_analyse_first(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = write_recording(tmp_path / "run.mcap", "mcap", n=4)
    code, _, err = run(["explain", str(log), "--frame", "1"], capsys)
    assert code == 2 and "is a recording" in err and "analyze" in err and "--out" in err
    # a rule ID where the run's folder goes points to the rule's own text
    code, _, err = run(["explain", "fd-pln-001"], capsys)
    assert code == 2 and "rule ID" in err and "frontdiag rules explain FD-PLN-001" in err
    assert "Traceback" not in err
    out = tmp_path / "res"
    assert main(["analyze", str(log), "--out", str(out), "-q", "--fail-on", "never"]) == 0
    capsys.readouterr()
    code, _, err = run(["explain", str(out), "--frame", "99"], capsys)
    assert code == 2 and "frames 0-3" in err
    code, stdout, _ = run(["explain", str(out), "--time", "0.1"], capsys)
    assert code == 0 and "frontend status" in stdout and "verdict (what the rules found)" in stdout
    # the frame as argument is --frame
    code, by_option, _ = run(["explain", str(out), "--frame", "2", "--json"], capsys)
    code2, by_argument, _ = run(["explain", str(out), "2", "--json"], capsys)
    assert code == code2 == 0 and json.loads(by_argument) == json.loads(by_option)
    assert json.loads(by_argument)["frame"] == 2
    code, _, err = run(["explain", str(out), "2", "--frame", "3"], capsys)
    assert code == 2 and "two frames" in err
    code, _, err = run(["explain", str(out), "2", "--time", "0.1"], capsys)
    assert code == 2 and "exactly one" in err


def test_eval_finds_labels_from_the_manifest_and_gates_on_accuracy(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = write_recording(tmp_path / "run.mcap", "mcap", n=6, shift=4)
    out = tmp_path / "res"
    assert main(["analyze", str(log), "--out", str(out), "-q", "--fail-on", "never"]) == 0
    capsys.readouterr()
    code, _, err = run(["eval", str(out)], capsys)  # no labels beside the recording yet
    assert code == 2 and "run.mcap.labels.csv" in err
    # a label the rules cannot find (exposure step over the whole run): recall 0, F1 0
    (tmp_path / "run.mcap.labels.csv").write_text(
        "t_start_ns,t_end_ns,condition\n0,1800000000000000000,exposure_step\n")
    code, stdout, _ = run(["eval", str(out), "--json"], capsys)
    doc = json.loads(stdout)
    cond = next(c for c in doc["conditions"] if c["condition"] == "exposure_step")
    assert cond["frame_recall"] == 0 and cond["frame_f1"] == 0
    assert code == 0 and doc["gate"]["passed"]
    code, stdout, _ = run(["eval", str(out), "--min-recall", "0.5"], capsys)
    assert code == 1 and "accuracy gate failed" in stdout and "exposure_step" in stdout


def test_f1_is_zero_when_nothing_labelled_is_found() -> None:
    c = ConditionScore("exposure_step", ("camera",), 1, 0, 10, 0, 0, 0, 50, 0)
    assert c.recall == 0 and c.precision is None and c.f1 == 0.0


def test_config_file_sets_the_frontend_and_is_written_back(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "frontend.toml"
    cfg.write_text("[camera]\nn_features = 600\nfast_threshold = 25\n\n[lidar]\nvoxel_size_m = 0.3\n")
    log = write_recording(tmp_path / "run.mcap", "mcap", n=3)
    out = tmp_path / "res"
    code, _, _ = run(["analyze", str(log), "--config", str(cfg), "--ratio", "0.7", "--out",
                      str(out), "-q", "--fail-on", "never"], capsys)
    assert code == 0
    man = json.loads((out / "manifest.json").read_text())
    assert man["params"]["camera"]["n_features"] == 600
    assert man["params"]["camera"]["fast_threshold"] == 25
    assert man["params"]["camera"]["ratio"] == 0.7  # the option wins over the file
    written = tomllib.loads((out / "frontend.toml").read_text())
    assert written["camera"]["n_features"] == 600
    assert load_config(out / "frontend.toml").camera.ratio == 0.7  # reads back
    cfg.write_text("[camera]\nn_feature = 600\n")
    code, _, err = run(["analyze", str(log), "--config", str(cfg), "-q"], capsys)
    assert code == 2 and "n_feature" in err and len(err.strip().splitlines()) <= 2
    with pytest.raises(ConfigError, match="ratio"):
        load_config(None, {"camera": {"ratio": 1.5}})


def test_the_python_api_takes_the_cli_names_and_returns_a_result(tmp_path: Path) -> None:
    log = write_recording(tmp_path / "plane.mcap", "mcap", n=6, shift=4)
    res = frontdiag.analyze(log, intrinsics=(120.0, 120.0, 80.0, 60.0),
                            features=500, fail_on="warn")
    assert isinstance(res, frontdiag.Result)
    df = res.to_pandas()
    assert isinstance(df, pd.DataFrame) and len(df) == 6
    assert res.manifest["intrinsics"]["K"][0][0] == 120.0
    assert res.manifest["params"]["camera"]["n_features"] == 500
    assert res.gate is not None and res.gate.exit_code == 1 and not res.passed
    assert not res.episodes.empty
    written = res.save(tmp_path / "res")
    assert (tmp_path / "res" / "frames.parquet") in written
    with pytest.raises(ConfigError):
        frontdiag.analyze(log, intrinsics=(1.0, 2.0))


def test_config_defaults_are_the_frontends_defaults() -> None:
    from frontdiag.camera.frontend import CameraParams
    from frontdiag.config import FrontendConfig
    from frontdiag.lidar.frontend import LidarParams

    cfg = FrontendConfig()
    assert cfg.camera_params() == CameraParams()
    assert cfg.lidar_params() == LidarParams()


def test_budget_projection_names_provenance_and_says_when_inputs_disagree(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import dataclasses

    from frontdiag.budget import measured, model, render, targets

    sample = Path(__file__).resolve().parents[1] / "sample_logs" / "dock_corridor.mcap"
    out = tmp_path / "res"
    assert main(["analyze", str(sample), "--no-camera", "--max-frames", "12", "--out", str(out),
                 "-q", "--fail-on", "never"]) == 0
    orin = targets.load_target("orin-nano")
    assert orin.provenance == "reference"
    rep = measured.measured_report(out, model.Workload(), orin, orin, "the same file")
    assert "Matching projected" not in rep.method  # LiDAR only: no matching to project
    assert not any("UNRELIABLE" in n or "faster than" in n for n in rep.notes)
    grid = render.measured_grids(rep)[0]
    util = next(r for r in grid.rows if r[0].startswith("Utilisation"))
    assert util[grid.headers.index("p50 (ms)")] != ""  # the target's figure under the target
    c = orin.coefficients["icp_solve_ns_per_point"]
    skewed = dataclasses.replace(orin, coefficients={
        **orin.coefficients, c.name: dataclasses.replace(c, value=c.value * 100)})
    rep = measured.measured_report(out, model.Workload(), orin, skewed, "skewed")
    assert any(n.startswith("UNRELIABLE (lidar)") for n in rep.notes)
    assert render.measured_grids(rep)[0].title.startswith("UNRELIABLE ESTIMATE")
    code, stdout, _ = run(["budget"], capsys)
    assert code == 0 and "reference estimates of per-unit costs" in stdout and "(given)" in stdout


def test_odometry_logged_after_a_scan_is_used_as_its_prior() -> None:
    sample = Path(__file__).resolve().parents[1] / "sample_logs" / "dock_corridor.mcap"
    res = frontdiag.analyze(sample, no_camera=True, max_frames=8, no_rules=True)
    assert res.manifest["topics"]["odometry"] == "/odom"
    priors = list(res.table["lidar_prior"])
    assert len(priors) == 8  # buffered scans still respect --max-frames
    assert priors[0] == "none" and set(priors[1:]) == {"odometry"}


def test_calibration_spread_is_kept_and_a_noisy_one_is_called_unreliable(tmp_path: Path) -> None:
    import dataclasses

    from frontdiag.budget import measured, model, render, targets

    sample = Path(__file__).resolve().parents[1] / "sample_logs" / "dock_corridor.mcap"
    out = tmp_path / "res"
    assert main(["analyze", str(sample), "--no-camera", "--max-frames", "6", "--out", str(out),
                 "-q", "--fail-on", "never"]) == 0
    orin = targets.load_target("orin-nano")
    c = orin.coefficients["voxel_ns_per_point"]
    noisy = dataclasses.replace(orin, provenance="calibrated", coefficients={
        **orin.coefficients, c.name: dataclasses.replace(c, how="measured", spread=3.5)})
    back = targets.parse_target(tomllib.loads(targets.target_to_toml(noisy)))
    assert back.coefficients[c.name].spread == 3.5  # the target file keeps it
    rep = measured.measured_report(out, model.Workload(), orin, noisy, "noisy")
    assert any(n.startswith("UNRELIABLE (calibration)") and "voxel_ns_per_point ×3.5" in n
               for n in rep.notes)
    assert render.measured_grids(rep)[0].title.startswith("UNRELIABLE ESTIMATE")


def test_explain_states_what_matching_did_on_a_frame_with_no_pose() -> None:
    from frontdiag.cli.explain import matching_facts

    row = {"n_keypoints": 1000, "ratio_reject_rate": 0.98, "ratio_ambiguous_rate": 0.03,
           "n_matches": 13, "in_frame_twin_rate": 0.02}
    assert matching_facts(row, 1.0) == (
        "1000 keypoints; the ratio test refused 98% (3% with two close candidates, 95% with "
        "none close); 13 matches kept; 2% of the keypoints have a copy in the same view; the "
        "previous frame is 1 s earlier")
    # what is missing is left out, not printed as nan
    assert matching_facts({"n_keypoints": 4, "n_matches": float("nan")}, None) == "4 keypoints"


def _mcap_without(src: Path, dst: Path, *drop: str) -> Path:
    """A copy of an MCAP file without the messages of ``drop`` (raw bytes, nothing re-encoded)."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with src.open("rb") as f, dst.open("wb") as g:
        r = make_reader(f)
        w = Writer(g)
        head = r.get_header()
        w.start(head.profile, head.library)
        schemas: dict[int, int] = {}
        chans: dict[int, int] = {}
        for schema, ch, msg in r.iter_messages(log_time_order=False):
            if ch.topic in drop:
                continue
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if ch.id not in chans:
                chans[ch.id] = w.register_channel(ch.topic, ch.message_encoding,
                                                  schemas.get(ch.schema_id, 0), ch.metadata)
            w.add_message(chans[ch.id], msg.log_time, msg.data, msg.publish_time, msg.sequence)
        w.finish()
    return dst


def test_without_an_odometry_topic_the_prior_comes_from_tf(tmp_path: Path) -> None:
    """A recording that kept /tf and /tf_static but not /odom: the LiDAR's prior is the
    odometry frame's transform on /tf chained to the LiDAR's frame by /tf_static (odom →
    base_link → lidar), and the manifest says so; the same LiDAR rows as with /odom (placed at
    the LiDAR by /tf_static too) on this straight drive. Without /tf_static nothing joins base_link to the LiDAR's frame: a
    constant-velocity prior, and the note names what /tf held."""
    sample = Path(__file__).resolve().parents[1] / "sample_logs" / "dock_corridor.mcap"
    kw = {"no_camera": True, "max_frames": 8, "no_rules": True}
    ref = frontdiag.analyze(sample, **kw)
    # with /odom, /tf_static still says where the LiDAR sits on the base the odometry is of
    assert ("/lidar/points: /odom gives poses of base_link; /tf_static places the LiDAR "
            "(lidar) in it, so the prior is the LiDAR's own motion") in ref.manifest["notes"]
    tf = frontdiag.analyze(_mcap_without(sample, tmp_path / "tf.mcap", "/odom"), **kw)
    assert tf.manifest["topics"]["odometry"] is None
    assert list(tf.table["lidar_prior"]) == list(ref.table["lidar_prior"])
    assert set(tf.table["lidar_prior"][1:]) == {"odometry"}
    assert ("/lidar/points: no odometry topic; motion prior from /tf and /tf_static: odom → "
            "base_link → lidar") in tf.manifest["notes"]
    for col in ("icp_rmse_m", "icp_fitness", "lidar_eig_min", "deskew_m"):
        assert tf.table[col].to_numpy() == pytest.approx(ref.table[col].to_numpy(), rel=1e-3,
                                                         abs=1e-6, nan_ok=True), col
    lone = frontdiag.analyze(_mcap_without(sample, tmp_path / "lone.mcap", "/odom",
                                           "/tf_static"), **kw)
    assert set(lone.table["lidar_prior"][2:]) == {"constant_velocity"}
    assert any("/tf chains no odometry frame to the LiDAR's frame (odometry transforms seen: "
               "odom → base_link)" in n for n in lone.manifest["notes"])


def _tf(parent: str, child: str, t_ns: int, xyz: tuple[float, float, float],
        yaw: float = 0.0):  # type: ignore[no-untyped-def]
    """A TransformStamped as a deserialised message reads: yaw about z, then ``xyz``."""
    from types import SimpleNamespace as N

    import numpy as np

    q = N(x=0.0, y=0.0, z=float(np.sin(yaw / 2)), w=float(np.cos(yaw / 2)))
    return N(header=N(frame_id=parent, stamp=N(sec=t_ns // 10**9, nanosec=t_ns % 10**9)),
             child_frame_id=child,
             transform=N(translation=N(x=xyz[0], y=xyz[1], z=xyz[2]), rotation=q))


def test_tf_odometry_chains_the_sensor_frame_through_the_static_tree() -> None:
    """T_odom_lidar = T_odom_base(t) · T_base_mount · T_mount_lidar, frames compared without
    ROS 1's leading slash; map → odom (a localiser's corrections) is not odometry; each pose
    is handed out once, in order, and only after the sensor's frame is chained."""
    from types import SimpleNamespace as N

    import numpy as np

    from frontdiag.io.decode import pose_matrix
    from frontdiag.io.tf import TfOdometry

    def T(xyz, yaw):  # type: ignore[no-untyped-def]
        return pose_matrix(xyz, (0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)))

    tf = TfOdometry()
    tf.add(N(transforms=[_tf("/base_link", "mount", 0, (0.5, 0.0, 0.3), 0.2),
                         _tf("mount", "lidar", 0, (0.0, 0.1, 0.0), -0.5)]), static=True)
    tf.add(N(transforms=[_tf("map", "odom", 1_000, (9.0, 9.0, 0.0), 1.0),
                         _tf("odom", "base_link", 1_000, (1.0, 2.0, 0.0), 0.3),
                         _tf("odom", "caster", 1_000, (1.0, 2.0, 0.0), 0.3)]), static=False)
    assert tf.poses() == [] and not tf.resolved
    assert not tf.resolve("camera")  # no static path from it
    assert tf.resolve("/lidar") and tf.describe() == "odom → base_link → mount → lidar"
    assert "odom" not in tf.dynamic and len(tf.dynamic["caster"]) == 0  # map → odom is not odometry
    tf.add(N(transforms=[_tf("odom", "base_link", 2_000, (1.5, 2.0, 0.0), 0.4),
                         _tf("odom", "base_link", 1_500, (0.0, 0.0, 0.0), 0.0)]), static=False)
    got = tf.poses()
    assert [t for t, _ in got] == [1_000, 2_000]  # the stamp going back is dropped
    X = T((0.5, 0.0, 0.3), 0.2) @ T((0.0, 0.1, 0.0), -0.5)
    for (_, P), base in zip(got, (T((1.0, 2.0, 0.0), 0.3), T((1.5, 2.0, 0.0), 0.4)),
                            strict=True):
        np.testing.assert_allclose(P, base @ X, atol=1e-12)
    assert tf.poses() == [] and len(tf.dynamic["base_link"]) == 0  # handed out, not kept
    tf.add(N(transforms=[_tf("odom", "base_link", 3_000, (2.0, 2.0, 0.0), 0.5),
                         _tf("odom", "wheel", 3_000, (0.0, 0.0, 0.0))]), static=False)
    assert [t for t, _ in tf.poses()] == [3_000]
    assert "wheel" not in tf.dynamic  # once chained, only the chained frame is followed


EVO_TF = Path(__file__).resolve().parents[2] / "shared" / "data" / "rosbags_evo"


@pytest.mark.parametrize("name", ["tf_example.bag", "tf_example"])
def test_tf_odometry_on_a_real_robots_transforms(name: str) -> None:
    """evo's recorded /tf (ROS 1 bag and ROS 2 folder): odom → base_footprint at 10 Hz on /tf,
    base_footprint → base_link on /tf_static. A sensor on base_link chains to the odometry
    through the static transform, and every recorded pose reaches the prior, in time order."""
    import numpy as np

    from frontdiag.io.readers import open_recording
    from frontdiag.io.tf import TfOdometry, transform_matrix

    path = EVO_TF / name
    if not path.exists():
        pytest.skip("../shared/data/rosbags_evo absent")
    tf = TfOdometry()
    base = []
    with open_recording(path) as rec:
        for raw in rec.messages(["/tf", "/tf_static"]):
            msg = rec.deserialize(raw)
            tf.add(msg, raw.topic == "/tf_static", raw.log_ns)
            if raw.topic == "/tf":
                base += [transform_matrix(tr.transform) for tr in msg.transforms]
    assert tf.resolve("base_link") and tf.describe() == "odom → base_footprint → base_link"
    poses = tf.poses()
    assert len(poses) == len(base) == 517
    stamps = [t for t, _ in poses]
    assert stamps == sorted(stamps) and len(set(stamps)) == 517
    mount = tf.static["base_link"][1]
    for (_, P), B in zip(poses[::50], base[::50], strict=True):
        np.testing.assert_allclose(P, B @ mount, atol=1e-12)


def test_info_says_where_the_lidar_prior_will_come_from(tmp_path: Path, capsys) -> None:
    """`info` names the odometry topic and /tf_static, or /tf where no odometry topic is."""
    sample = Path(__file__).resolve().parents[1] / "sample_logs" / "dock_corridor.mcap"
    code, out, _ = run(["info", str(sample)], capsys)
    assert code == 0 and ("odometry /odom, placed at the LiDAR by /tf_static where it joins "
                          "their frames") in " ".join(out.split())
    code, out, _ = run(["info", str(_mcap_without(sample, tmp_path / "tf.mcap", "/odom"))],
                       capsys)
    assert code == 0 and ("odometry from /tf (an odometry frame chained to the LiDAR's frame, "
                          "if one is)") in " ".join(out.split())


def _odom_as_poses(src: Path, dst: Path, msgtype: str) -> Path:
    """A copy of a ROS 2 MCAP file without /tf and /tf_static, its /odom rewritten as ``msgtype``
    (geometry_msgs PoseStamped or PoseWithCovarianceStamped) on /pose, the same stamps and
    poses; every other message copied as it was."""
    from mcap.reader import make_reader

    from frontdiag.io.writer import RecordingWriter

    with src.open("rb") as f, RecordingWriter(dst, "mcap") as w:
        for schema, ch, msg in make_reader(f).iter_messages(log_time_order=True):
            if ch.topic in ("/tf", "/tf_static") or schema is None:
                continue
            if ch.topic != "/odom":
                w.write_raw(ch.topic, schema.name, msg.data, msg.log_time)
                continue
            o = w.ts.deserialize_cdr(msg.data, "nav_msgs/msg/Odometry")
            p, q = o.pose.pose.position, o.pose.pose.orientation
            pose = {"position": {"x": p.x, "y": p.y, "z": p.z},
                    "orientation": {"x": q.x, "y": q.y, "z": q.z, "w": q.w}}
            if msgtype.endswith("PoseWithCovarianceStamped"):
                pose = {"pose": pose, "covariance": [0.0] * 36}
            header = {"stamp": {"sec": o.header.stamp.sec, "nanosec": o.header.stamp.nanosec},
                      "frame_id": o.header.frame_id}
            w.write("/pose", msgtype, {"header": header, "pose": pose}, msg.log_time)
    return dst


@pytest.mark.parametrize("msgtype", ["geometry_msgs/msg/PoseStamped",
                                     "geometry_msgs/msg/PoseWithCovarianceStamped"])
def test_a_pose_topic_named_by_odom_topic_is_the_lidar_prior(tmp_path: Path, msgtype: str) -> None:
    """--odom-topic takes a pose topic: the LiDAR rows are those the same poses give as
    nav_msgs/Odometry; a pose topic is never taken unasked (the notes name it instead), and
    the notes say that a pose names no child frame."""
    sample = Path(__file__).resolve().parents[1] / "sample_logs" / "dock_corridor.mcap"
    kw = {"no_camera": True, "max_frames": 8, "no_rules": True}
    ref = frontdiag.analyze(_mcap_without(sample, tmp_path / "odom.mcap", "/tf", "/tf_static"),
                            **kw)
    assert set(ref.table["lidar_prior"][1:]) == {"odometry"}
    poses = _odom_as_poses(sample, tmp_path / "poses.mcap", msgtype)
    got = frontdiag.analyze(poses, odom_topic="/pose", **kw)
    assert got.manifest["topics"]["odometry"] == "/pose"
    assert list(got.table["lidar_prior"]) == list(ref.table["lidar_prior"])
    for col in ("icp_rmse_m", "icp_fitness", "lidar_eig_min", "deskew_m"):
        assert got.table[col].to_numpy() == pytest.approx(ref.table[col].to_numpy(), rel=1e-9,
                                                          abs=1e-12, nan_ok=True), col
    assert any("/pose names no child frame" in n for n in got.manifest["notes"])
    unasked = frontdiag.analyze(poses, **kw)
    assert unasked.manifest["topics"]["odometry"] is None
    assert set(unasked.table["lidar_prior"][2:]) == {"constant_velocity"}
    assert any("/pose (poses) could give it: pass --odom-topic /pose" in n
               for n in unasked.manifest["notes"])
