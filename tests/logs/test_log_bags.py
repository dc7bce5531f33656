"""Logs as people have them: ROS 1 MCAP (``mcap convert`` output), ROS 1 ``.bag`` and ROS 2
``.db3`` bag directories (issue 23).

The same simulated drive is written four ways — ROS 2 MCAP by ``evperc simulate``, and from it
(tests/bag_writers.py, third-party writers only) ROS 1 MCAP, ``.bag``, ``.db3`` — and each is
run through the real CLI: the outputs must be identical, frame by frame and cell by cell. The
four files hold the same numbers (float64 poses, float32 points, integer stamps) in different
encodings, so exact equality is the expectation, not a tolerance: any difference is a decoding
or ordering error.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import evperc
from evperc.cli import cli
from evperc.errors import LogError
from evperc.logs.factory import open_log
from tests.bag_writers import write_ros1_mcap, write_rosbag1, write_rosbag2_sqlite
from tests.e2e.test_bad_input import assert_one_line_error
from tests.logs.reference import S0
from tests.mcap_writers import transform, write_ros2_mcap

DATA = Path(__file__).resolve().parents[1] / "data" / "osm"
MS = 1_000_000
KINDS = ("ros2_mcap", "ros1_mcap", "bag", "db3")


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A 2 s simulated drive (20 scans) as the four kinds of log, and its map."""
    root = tmp_path_factory.mktemp("kinds")
    res = CliRunner().invoke(cli, [
        "simulate", "--map", str(DATA / "helsinki_buildings.geojson"), "--roads",
        str(DATA / "helsinki_roads.geojson"), "--out", str(root / "sim"), "--seconds", "2",
        "--seed", "5"])
    assert res.exit_code == 0, res.output
    src = root / "sim" / "drive.mcap"
    return {"ros2_mcap": src, "ros1_mcap": write_ros1_mcap(src, root / "ros1.mcap"),
            "bag": write_rosbag1(src, root / "drive.bag"),
            "db3": write_rosbag2_sqlite(src, root / "drive_db3"),
            "map": root / "sim" / "map.geojson"}


@pytest.fixture(scope="module")
def runs(drive: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("runs")
    dirs = {}
    for kind in KINDS:
        res = CliRunner().invoke(cli, ["run", str(drive[kind]), "--map", str(drive["map"]),
                                       "--out", str(out / kind)])
        assert res.exit_code == 0, (kind, res.output)
        dirs[kind] = out / kind
    return dirs


def test_the_files_are_the_kinds_they_claim(drive):
    """Checked with the writers' own readers, not evperc's."""
    assert drive["ros2_mcap"].read_bytes()[:8] == b"\x89MCAP0\r\n"
    assert drive["bag"].read_bytes()[:13] == b"#ROSBAG V2.0\n"
    (db3,) = drive["db3"].glob("*.db3")
    assert db3.read_bytes()[:16] == b"SQLite format 3\x00"
    assert "sqlite3" in (drive["db3"] / "metadata.yaml").read_text()
    from mcap.reader import make_reader

    with drive["ros1_mcap"].open("rb") as f:
        summary = make_reader(f).get_summary()
    assert {c.message_encoding for c in summary.channels.values()} == {"ros1"}
    assert {s.encoding for s in summary.schemas.values()} == {"ros1msg"}
    assert "sensor_msgs/PointCloud2" in {s.name for s in summary.schemas.values()}


def test_four_kinds_give_identical_decisions(runs):
    ref = evperc.load(runs["ros2_mcap"])
    assert len(ref) == 20 and ref.manifest["summary"]["skipped_scans"] == {}
    decided = np.zeros(len(ref.decision_codes), np.int64)
    for frame in ref.frames:
        decided += frame.decision_counts
    assert np.count_nonzero(decided) >= 3  # the drive decides something: not a vacuous test
    for kind in KINDS[1:]:
        run = evperc.load(runs[kind])
        assert len(run) == len(ref) and run.manifest["summary"]["skipped_scans"] == {}, kind
        assert run.manifest["world_frame"] == ref.manifest["world_frame"]
        for a, b in zip(run.frames, ref.frames, strict=True):
            assert a.stamp_ns == b.stamp_ns and a.origin == b.origin, kind
            np.testing.assert_array_equal(a.pose, b.pose, err_msg=kind)
            np.testing.assert_array_equal(a.decision, b.decision, err_msg=kind)
            np.testing.assert_array_equal(a.masses, b.masses, err_msg=kind)
            np.testing.assert_array_equal(a.zeta, b.zeta, err_msg=kind)


def test_info_names_the_kind_and_the_same_topics(drive):
    infos = {}
    for kind in KINDS:
        res = CliRunner().invoke(cli, ["info", str(drive[kind]), "--json"])
        assert res.exit_code == 0, res.output
        infos[kind] = json.loads(res.output)
    assert [infos[k]["kind"] for k in KINDS] == ["mcap", "mcap", "rosbag1", "rosbag2"]
    counts = {k: {t["topic"]: t["messages"] for t in infos[k]["topics"]} for k in KINDS}
    assert counts["ros2_mcap"] == {"/lidar/points": 20, "/odom": 111, "/tf": 111,
                                   "/tf_static": 1, "/gnss": 23}
    encodings = {k: {t["encoding"] for t in infos[k]["topics"]} for k in KINDS}
    assert encodings == {"ros2_mcap": {"cdr"}, "ros1_mcap": {"ros1"}, "bag": {"ros1"},
                         "db3": {"cdr"}}
    for kind in KINDS:
        assert counts[kind] == counts["ros2_mcap"], kind
        for key in ("start_ns", "end_ns", "detected", "mean_points_per_scan", "indexed"):
            assert infos[kind][key] == infos["ros2_mcap"][key], (kind, key)


def test_batch_reads_a_bag_and_a_db3_directory(drive, runs, tmp_path):
    res = CliRunner().invoke(cli, ["batch", str(drive["bag"]), str(drive["db3"]), "--map",
                                   str(drive["map"]), "--out", str(tmp_path / "root"),
                                   "--workers", "1"])
    assert res.exit_code == 0, res.output
    ref = evperc.load(runs["ros2_mcap"])
    for name in ("drive", "drive_db3"):
        run = evperc.load(tmp_path / "root" / name)
        assert len(run) == len(ref)
        for a, b in zip(run.frames, ref.frames, strict=True):
            np.testing.assert_array_equal(a.decision, b.decision)


# --- every ROS message type, ROS 1 and ROS 2 alike ---------------------------------------

def _posed(path, **kw):
    log = open_log(path, **kw)
    scans = list(log.scans())
    return log, [(s.stamp_ns, s.planar, s.points, s.T_world_sensor) for s in scans]


@pytest.mark.parametrize("pose_covariance", [False, True])
def test_laserscan_pose_stamped_navsatfix_in_every_kind(tmp_path, pose_covariance):
    """LaserScan, PoseStamped / PoseWithCovarianceStamped, NavSatFix and /tf_static: the ROS 2
    MCAP's posed scans and GNSS fixes come out of the three other kinds unchanged."""
    rng = np.random.default_rng(3)
    scans = [(S0 + i * 100 * MS, rng.uniform(1.0, 20.0, 90), -1.5, 0.033, "laser")
             for i in range(6)]
    poses = [(S0 - 50 * MS + i * 100 * MS, transform(x=2.0 * i, y=0.5 * i, yaw=0.1 * i))
             for i in range(8)]
    fixes = [(S0 + i * 200 * MS, 60.17 + 1e-5 * i, 24.94, 12.0) for i in range(3)]
    src = write_ros2_mcap(tmp_path / "a.mcap", laserscans=scans, pose_stamped=poses,
                          pose_covariance=pose_covariance, fixes=fixes,
                          tf_static=[("base_link", "laser", transform(x=1.2, z=0.4))])
    kinds = {"ros1_mcap": write_ros1_mcap(src, tmp_path / "b.mcap"),
             "bag": write_rosbag1(src, tmp_path / "c.bag"),
             "db3": write_rosbag2_sqlite(src, tmp_path / "d")}
    ref_log, ref = _posed(src)
    assert len(ref) == 6 and all(planar for _, planar, _, _ in ref)
    for kind, path in kinds.items():
        log, got = _posed(path)
        assert log.pose_topics == ref_log.pose_topics == ("topic", ["/pose"]), kind
        for (ta, pa, xa, Ta), (tb, pb, xb, Tb) in zip(got, ref, strict=True):
            assert ta == tb and pa == pb, kind
            np.testing.assert_array_equal(xa, xb, err_msg=kind)
            np.testing.assert_array_equal(Ta, Tb, err_msg=kind)
        np.testing.assert_array_equal(log.gnss_fixes(), ref_log.gnss_fixes(), err_msg=kind)
        assert len(log.gnss_fixes()) == 3


def test_ros1_latched_tf_static_and_tf1_messages(drive, tmp_path):
    """A ROS 1 bag whose /tf_static connection is latched (ROS 1's transient-local) and whose
    static transform is stamped an hour before the recording (the static publisher started
    long before), with tf's ``tf/tfMessage`` on /tf and /tf_static: the TF tree poses every
    scan exactly as the ROS 2 MCAP's tf2 messages do."""
    from rosbags.rosbag1 import Reader

    src = drive["ros2_mcap"]
    bag = write_rosbag1(src, tmp_path / "tf1.bag", tf_type="tf/msg/tfMessage",
                        static_stamp_ns=S0 - 3600 * 10**9)
    with Reader(bag) as reader:  # the file is what the test says (rosbags' own reader)
        latching = {c.topic: c.ext.latching for c in reader.connections}
        types = {c.topic: c.msgtype for c in reader.connections}
    assert latching["/tf_static"] == 1 and latching["/tf"] is None
    assert types["/tf"] == types["/tf_static"] == "tf/msg/tfMessage"
    ros1_mcap = write_ros1_mcap(src, tmp_path / "tf1.mcap", tf_type="tf/msg/tfMessage")
    ref_log, ref = _posed(src, pose_topic="/tf")
    assert len(ref) == 20
    for path in (bag, ros1_mcap):
        log, got = _posed(path, pose_topic="/tf")
        assert log.static_tf_topics == ["/tf_static"] and log.stats == {}
        assert log.posed_in == ref_log.posed_in == "map"
        for (ta, _, xa, Ta), (tb, _, xb, Tb) in zip(got, ref, strict=True):
            assert ta == tb
            np.testing.assert_array_equal(xa, xb)
            np.testing.assert_array_equal(Ta, Tb)


def test_rosbags_mcap_bag_directory_reads_like_its_mcap_file(tmp_path):
    """A ROS 2 bag directory with MCAP storage (metadata.yaml + .mcap), given as the
    directory, is read through rosbags and gives what its .mcap file gives."""
    from tests.mcap_writers import write_rosbags_mcap

    clouds = [(S0 + i * 100 * MS, np.random.default_rng(i).uniform(-9, 9, (50, 3)), "velodyne")
              for i in range(3)]
    odom = [(S0 - 50 * MS + i * 100 * MS, transform(x=0.3 * i)) for i in range(5)]
    mcap_file = write_rosbags_mcap(tmp_path / "bag", clouds=clouds, odometry=odom)
    by_dir, by_file = open_log(tmp_path / "bag"), open_log(mcap_file)
    assert (by_dir.source.kind, by_file.source.kind) == ("rosbag2", "mcap")
    a, b = list(by_dir.scans()), list(by_file.scans())
    assert len(a) == len(b) == 3
    for sa, sb in zip(a, b, strict=True):
        assert sa.stamp_ns == sb.stamp_ns
        np.testing.assert_array_equal(sa.points, sb.points)
        np.testing.assert_array_equal(sa.T_world_sensor, sb.T_world_sensor)


# --- errors -------------------------------------------------------------------------------

def _run(log: Path, tmp_path: Path) -> tuple[int, str]:
    res = CliRunner().invoke(cli, ["run", str(log), "--no-map", "--out", str(tmp_path / "o")])
    return res.exit_code, res.output


def test_truncated_bag_is_one_line_exit_2(drive, tmp_path):
    data = drive["bag"].read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])  # recording killed: the index at the end is gone
    code, out = _run(cut, tmp_path)
    assert_one_line_error(code, out, "cut.bag", "cannot read this ROS 1 bag", "rosbag reindex")
    assert not (tmp_path / "o" / "manifest.json").exists()


def test_garbled_bag_header_is_one_line_exit_2(tmp_path):
    bad = tmp_path / "bad.bag"
    bad.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 4)
    code, out = _run(bad, tmp_path)
    assert_one_line_error(code, out, "bad.bag", "cannot read this ROS 1 bag")


def test_old_bag_format_is_one_line_exit_2(tmp_path):
    old = tmp_path / "old.bag"
    old.write_bytes(b"#ROSBAG V1.2\n" + bytes(64))
    code, out = _run(old, tmp_path)
    assert_one_line_error(code, out, "old.bag", "format V1.2", "rosbag fix")


def test_db3_without_metadata_is_one_line_exit_2(drive, tmp_path):
    (db3,) = drive["db3"].glob("*.db3")
    lone = tmp_path / "lone"
    lone.mkdir()
    shutil.copy(db3, lone / db3.name)
    code, out = _run(lone / db3.name, tmp_path)
    assert_one_line_error(code, out, db3.name, "without the metadata.yaml",
                          f"ros2 bag reindex {lone}")
    code, out = _run(lone, tmp_path)  # the directory, without metadata.yaml
    assert_one_line_error(code, out, str(lone), "is a directory without a metadata.yaml")


def test_db3_file_with_its_metadata_reads_the_bag(drive):
    (db3,) = drive["db3"].glob("*.db3")
    log = open_log(db3)
    assert log.source.kind == "rosbag2" and len(list(log.scans())) == 20


def test_unknown_content_names_what_was_found(tmp_path):
    png = tmp_path / "drive.bag"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(32))
    with pytest.raises(LogError) as err:
        open_log(png)
    text = str(err.value)
    assert "\n" not in text
    assert text.startswith(f"{png}: not an MCAP file or bag: it starts with 89 50 4e 47")


def test_damaged_bag_chunk_ends_the_stream_with_one_warning(drive, tmp_path, caplog):
    """Zeroed bytes in the middle of a .bag (its index intact): the scans before the damage
    are read, the stream then ends with one warning, and info says the log is incomplete."""
    data = bytearray(drive["bag"].read_bytes())
    middle = len(data) // 2
    data[middle:middle + 20_000] = bytes(20_000)
    bad = tmp_path / "damaged.bag"
    bad.write_bytes(bytes(data))
    log = open_log(bad)
    with caplog.at_level("WARNING"):
        scans = list(log.scans())
        list(log.scans())  # a second pass: no second warning
    assert 0 < len(scans) < 20
    warnings = [r for r in caplog.records if "truncated or damaged" in r.getMessage()]
    assert len(warnings) == 1 and "damaged.bag" in warnings[0].getMessage()
    info = log.info()
    assert info["complete"] is False and "unreadable data" in info["stopped"]


def test_kind_goes_by_content_not_by_name(drive, tmp_path):
    """A ROS 1 bag saved as ``.mcap`` is still read as a ROS 1 bag."""
    misnamed = tmp_path / "drive.mcap"
    shutil.copy(drive["bag"], misnamed)
    log = open_log(misnamed)
    assert log.source.kind == "rosbag1" and len(list(log.scans())) == 20


def test_db3_without_message_definitions_uses_the_bundled_types(drive, tmp_path):
    """ROS 2 bags recorded before Iron carry no message definitions (an empty
    message_definitions table here, as rosbags reads such bags): the types come from
    rosbags' bundled store, and the scans are those of the bag with definitions."""
    import sqlite3

    old = tmp_path / "old_bag"
    shutil.copytree(drive["db3"], old)
    (db3,) = old.glob("*.db3")
    with sqlite3.connect(db3) as db:
        db.execute("DELETE FROM message_definitions")
    from rosbags.rosbag2 import Reader

    with Reader(old) as reader:  # the copy really has no definitions (rosbags' own reader)
        assert {c.msgdef.format.name for c in reader.connections} == {"NONE"}
    a, b = list(open_log(old).scans()), list(open_log(drive["db3"]).scans())
    assert len(a) == len(b) == 20
    for sa, sb in zip(a, b, strict=True):
        assert sa.stamp_ns == sb.stamp_ns
        np.testing.assert_array_equal(sa.points, sb.points)
        np.testing.assert_array_equal(sa.T_world_sensor, sb.T_world_sensor)


@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_of_log_gives_the_lidars_layers(drive: dict[str, Path], kind: str) -> None:
    # the simulated ibeo4's 4 layers, written as each point's ring by `evperc simulate`
    assert open_log(drive[kind]).sensor_layers() == (4, "ring field")
