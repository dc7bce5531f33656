"""`evperc export`: the run's object list as foxglove.SceneUpdate on /evperc/objects, read
back with the mcap reader and decoded with the schema stored in the file (mcap_protobuf)."""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

import evperc
from evperc.config import load_config
from evperc.output.export import export_mcap
from evperc.output.objects import OBJECT_DTYPE
from evperc.runner import RunRequest, run
from tests.e2e.scenes import write_street_drive
from tests.render.conftest import make_frame, write_run

RES = 0.5          # m per cell; window 8 rows × 10 cols from the lattice origin
STAMPS = [7_000_000_000 + k * 100_000_000 for k in range(3)]
MATCHING_ID = 0    # foxglove.SceneEntityDeletion.Type


def record(track_id: int, state: int, rows: range, cols: range, velocity: tuple[float, float],
           age: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """One object over the cells ``rows × cols`` (window row 0 south, col 0 west), with its
    bbox, extent and centroid from the cell edges and centres; and its flat cell indices."""
    o = np.zeros((), OBJECT_DTYPE)
    o["track_id"], o["state"], o["age_frames"] = track_id, state, age
    o["cell_count"] = len(rows) * len(cols)
    o["bbox_m"] = [cols[0] * RES, rows[0] * RES, (cols[-1] + 1) * RES, (rows[-1] + 1) * RES]
    o["extent_m"] = [len(cols) * RES, len(rows) * RES]
    o["centroid_m"] = [(np.mean(cols) + 0.5) * RES, (np.mean(rows) + 0.5) * RES]
    o["velocity_m_per_s"] = velocity
    o["speed_sigma_m_per_s"], o["mean_betp_moving"] = 0.25, 0.8
    cells = np.array([r * 10 + c for r in rows for c in cols], np.uint32)
    return o, cells


def frame_objects(*objects: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    if not objects:
        return np.zeros(0, OBJECT_DTYPE), np.zeros(0, np.uint32)
    return (np.array([o for o, _ in objects], OBJECT_DTYPE),
            np.concatenate([c for _, c in objects]))


def read(path: Path) -> dict[str, list]:
    """Decoded messages by topic, in log-time order."""
    out: dict[str, list] = {}
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for schema, channel, _, decoded in reader.iter_decoded_messages():
            out.setdefault(channel.topic, []).append((schema.name, decoded))
    return out


def yaw_of(q) -> float:
    assert q.x == q.y == 0.0
    return 2 * math.atan2(q.z, q.w)


def test_objects_exported_as_scene_updates(tmp_path: Path) -> None:
    """Frame 0: car 1 moving at (3, 4) m/s (5 m/s, 53.13° from east) over rows 1-2 × cols 2-4,
    car 2 stopped over rows 5-6 × cols 7-8; frame 1: car 1 only, now at (0, -2) m/s;
    frame 2: no object. The cube of car 1 is centred on its bbox, x 1.0..2.5, y 0.5..1.5."""
    frames = [make_frame(8, 10, resolution_m=RES, stamp_ns=s, index=k)
              for k, s in enumerate(STAMPS)]
    objects = [frame_objects(record(1, 1, range(1, 3), range(2, 5), (3.0, 4.0)),
                             record(2, 2, range(5, 7), range(7, 9), (0.0, 0.0))),
               frame_objects(record(1, 1, range(1, 3), range(3, 6), (0.0, -2.0))),
               frame_objects()]
    out = write_run(tmp_path / "run", frames, objects=objects)
    mcap = tmp_path / "objects.mcap"
    result = export_mcap(evperc.load(out), mcap)
    assert "/evperc/objects" in result["topics"]
    scenes = read(mcap)["/evperc/objects"]
    assert [name for name, _ in scenes] == ["foxglove.SceneUpdate"] * 3
    first, second, third = (s for _, s in scenes)

    # frame 0: one entity per object, in the grids' frame, nothing to delete yet
    assert sorted(e.id for e in first.entities) == ["track-1", "track-2"]
    assert not first.deletions
    car, parked = sorted(first.entities, key=lambda e: e.id)
    assert car.frame_id == "evperc"
    assert (car.timestamp.seconds, car.timestamp.nanos) == (7, 0)
    assert car.lifetime.seconds == car.lifetime.nanos == 0   # kept until deleted
    (cube,) = car.cubes
    assert (cube.pose.position.x, cube.pose.position.y) == (1.75, 1.0)
    assert (cube.size.x, cube.size.y) == (1.5, 1.0)
    assert cube.pose.position.z == pytest.approx(cube.size.z / 2)   # stands on the grid
    assert 0.0 < cube.color.a < 1.0
    (arrow,) = car.arrows
    # the tail on the centroid (x = mean of the cell centres 1.25, 1.75, 2.25; y of 0.75, 1.25)
    assert (arrow.pose.position.x, arrow.pose.position.y) == (1.75, 1.0)
    assert yaw_of(arrow.pose.orientation) == pytest.approx(math.atan2(4.0, 3.0), abs=1e-9)
    (text,) = car.texts
    assert text.text == "id 1  5.0 m/s"
    meta = {kv.key: kv.value for kv in car.metadata}
    assert meta["state"] == "moving" and meta["cell_count"] == "6"
    assert meta["age_frames"] == "4" and meta["speed_sigma_m_per_s"] == "0.25"
    assert float(meta["mean_betp_moving"]) == pytest.approx(0.8, abs=1e-6)

    # the stopped car: a box of another colour, no arrow
    (box,) = parked.cubes
    assert (box.pose.position.x, box.pose.position.y) == (4.0, 3.0)
    assert (box.size.x, box.size.y) == (1.0, 1.0)
    assert not parked.arrows
    assert (box.color.r, box.color.g, box.color.b) != (cube.color.r, cube.color.g, cube.color.b)
    assert {kv.key: kv.value for kv in parked.metadata}["state"] == "stopped"

    # frame 1: car 1 replaced (same id), heading south; car 2 vanished -> deleted by id
    (car,) = second.entities
    assert car.id == "track-1" and car.cubes[0].pose.position.x == 2.25
    assert yaw_of(car.arrows[0].pose.orientation) == pytest.approx(-math.pi / 2, abs=1e-9)
    # arrow length proportional to speed: 2 m/s now against 5 m/s before
    (now,) = car.arrows
    assert (now.shaft_length + now.head_length) / (arrow.shaft_length + arrow.head_length) \
        == pytest.approx(2.0 / 5.0, rel=1e-6)
    assert [(d.type, d.id) for d in second.deletions] == [(MATCHING_ID, "track-2")]
    assert (second.deletions[0].timestamp.seconds,
            second.deletions[0].timestamp.nanos) == (7, 100_000_000)

    # frame 2: no object, still an update, which deletes car 1
    assert not third.entities
    assert [(d.type, d.id) for d in third.deletions] == [(MATCHING_ID, "track-1")]


def test_run_without_objects_has_no_objects_channel(tmp_path: Path,
                                                    caplog: pytest.LogCaptureFixture) -> None:
    frames = [make_frame(8, 10, resolution_m=RES, stamp_ns=s) for s in STAMPS]
    out = write_run(tmp_path / "run", frames)
    assert all(f.objects is None for f in evperc.load(out).frames)
    mcap = tmp_path / "grids.mcap"
    with caplog.at_level(logging.INFO, logger="evperc.output.export"):
        result = export_mcap(evperc.load(out), mcap)
    with mcap.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    topics = {c.topic for c in summary.channels.values()}
    assert "/evperc/grid" in topics and "/evperc/objects" not in topics
    assert "foxglove.SceneUpdate" not in {s.name for s in summary.schemas.values()}
    assert "/evperc/objects" not in result["topics"]
    assert "no object list" in caplog.text


def test_objects_of_a_real_run(tmp_path: Path) -> None:
    """`evperc run` on the street drive (a car crossing north at 2 m/s) then export: each
    frame's update has one entity per object of the frame, centred on its bbox, deletes the
    tracks of the frame before that are gone, and each moving car's arrow points along its
    fitted velocity."""
    drive = write_street_drive(tmp_path / "street.mcap", n_scans=30)
    config = load_config(overrides={"grid.window_size_m": 40.0})
    run(RunRequest(log_path=drive, out_dir=tmp_path / "run", config=config))
    frames = list(evperc.load(tmp_path / "run").frames)
    assert sum(len(f.objects) for f in frames) > 0, "the crossing car is reported"
    export_mcap(evperc.load(tmp_path / "run"), tmp_path / "run.mcap")
    scenes = [s for _, s in read(tmp_path / "run.mcap")["/evperc/objects"]]
    assert len(scenes) == len(frames)
    before: set[str] = set()
    for frame, scene in zip(frames, scenes, strict=True):
        by_id = {e.id: e for e in scene.entities}
        now = {f"track-{t}" for t in frame.objects["track_id"]}
        assert sorted(by_id) == sorted(now)
        assert {d.id for d in scene.deletions} == before - now
        before = now
        for o in frame.objects:
            e = by_id[f"track-{o['track_id']}"]
            xmin, ymin, xmax, ymax = o["bbox_m"]
            c = e.cubes[0]
            assert c.pose.position.x == pytest.approx((xmin + xmax) / 2, abs=1e-9)
            assert c.pose.position.y == pytest.approx((ymin + ymax) / 2, abs=1e-9)
            # float32 extents in a float (protobuf double) field
            assert (c.size.x, c.size.y) == pytest.approx(tuple(o["extent_m"]), rel=1e-6)
            vx, vy = o["velocity_m_per_s"]
            if o["state"] == 1 and math.hypot(vx, vy) > 0:
                assert yaw_of(e.arrows[0].pose.orientation) == pytest.approx(
                    math.atan2(vy, vx), abs=1e-9)
