"""Vehicle boxes (evperc/objects/boxes.py): a moving vehicle's footprint completed to a box of
a vehicle's size on the side away from the sensor, in cells the scan is silent about. The
expected cells are worked out by hand from the geometry below, not by the code."""

from __future__ import annotations

import numpy as np

from evperc.fusion.twin import DECISION_CODES
from evperc.geo.window import Window
from evperc.objects.boxes import BoxParams, complete_boxes
from evperc.output.objects import OBJECT_DTYPE, OBJECT_STATES

RES = 0.5
WINDOW = Window(RES, 40, 40, 0, 0)  # the sensor: centre of cell (20, 20), (10.25, 10.25) m
PARAMS = BoxParams(length_m=4.4, width_m=1.8, min_length_m=3.0, min_width_m=1.0)
D = DECISION_CODES
FREE = np.full(WINDOW.shape, D["free"], np.uint8)


def _record(track: int, cells: list[tuple[int, int]], velocity: tuple[float, float],
            state: str = "moving") -> tuple[np.ndarray, np.ndarray]:
    rec = np.zeros(1, OBJECT_DTYPE)
    rec["track_id"] = track
    rec["state"] = OBJECT_STATES[state]
    rec["cell_count"] = len(cells)
    rec["velocity_m_per_s"] = velocity
    flat = np.array([r * WINDOW.cols + c for r, c in cells], np.uint32)
    return rec, flat


def _scene(free: list[tuple[int, int]] = ()) -> tuple[np.ndarray, np.ndarray]:
    """(m({F}), m({O})) of a scan that saw the ``free`` cells free and the car's rear face
    (column 30, rows 19-22) occupied; silent elsewhere."""
    f = np.zeros(WINDOW.shape, np.float32)
    o = np.zeros(WINDOW.shape, np.float32)
    for r, c in free:
        f[r, c] = 0.7
    o[19:23, 30] = 0.8
    return f, o


def test_a_car_ahead_gets_its_hidden_length_away_from_the_sensor() -> None:
    # a car driving +x ahead of the sensor: its rear face, cells (19-22, 30), centres
    # x 15.25, y 9.75-11.25; the box: u from 15.25 to 15.25 + 4.4 = 19.65 (columns 30-38);
    # w from 9.75 to 9.75 + 1.8 = 11.55 (rows 19-22: the face is as wide already)
    car, car_cells = _record(1, [(r, 30) for r in range(19, 23)], (5.0, 0.0))
    other, other_cells = _record(2, [(22, 37)], (0.0, 0.0), "stopped")
    objects = np.concatenate([car, other])
    cells = np.concatenate([car_cells, other_cells])
    # a return beyond the car's rear face in (21, 36) (not the first of its azimuth bin, so
    # not occupied in the sensor grid; its height above the ground in the heights layer)
    returns = np.zeros(WINDOW.shape, np.float32)
    returns[21, 36] = 0.9
    # the grid remembers an obstacle in (20, 33) (a pole the car hides now): not the car
    decision = np.full(WINDOW.shape, D["free"], np.uint8)
    decision[20, 33] = D["static"]
    decision[19, 34] = D["unknown"]  # never seen: the box may take it
    out, out_cells = complete_boxes(objects, cells, WINDOW, _scene(free=[(19, 38)]), decision,
                                    PARAMS, returns=returns)
    expected = ({(r, c) for r in range(19, 23) for c in range(30, 39)}
                - {(19, 38), (22, 37), (21, 36), (20, 33)})
    n = int(out["cell_count"][0])
    got = {divmod(int(f), WINDOW.cols) for f in out_cells[:n]}
    assert got == expected and n == 32
    # the other record is kept as it was, after the car's
    assert out["cell_count"][1] == 1 and int(out_cells[n]) == 22 * WINDOW.cols + 37
    # the record's geometry is the completed footprint's: centres x 15.25-19.25, y 9.75-11.25
    assert np.allclose(out["bbox_m"][0], (15.0, 9.5, 19.5, 11.5))
    assert np.allclose(out["extent_m"][0], (4.5, 2.0))
    xs = np.array([c for _, c in sorted(got)]) * RES + RES / 2
    assert np.isclose(out["centroid_m"][0, 0], xs.mean())
    # the inputs are unchanged
    assert objects["cell_count"][0] == 4 and len(cells) == 5


def test_a_car_behind_the_sensor_grows_the_other_way() -> None:
    # driving +x behind the sensor (its front face seen, x 5.25 at column 10): the box
    # extends towards -x, u from 5.25 - 4.4 = 0.85 to 5.25: centres 1.25-5.25, columns 2-10
    car, cells = _record(1, [(r, 10) for r in range(19, 23)], (5.0, 0.0))
    out, out_cells = complete_boxes(car, cells, WINDOW, _scene(), FREE, PARAMS)
    got = {divmod(int(f), WINDOW.cols) for f in out_cells}
    assert got == {(r, c) for r in range(19, 23) for c in range(2, 11)}


def test_people_stopped_objects_and_boxes_off_are_left_alone() -> None:
    person, person_cells = _record(1, [(10, 10), (10, 11)], (1.4, 0.0))  # 0.5 m across
    out, out_cells = complete_boxes(person, person_cells, WINDOW, _scene(), FREE, PARAMS)
    assert out is person and out_cells is person_cells
    # a cyclist seen from its side: 2 m along its velocity (centres 1.5 m apart), one cell
    # across: neither a car's side (3 m) nor its rear (1 m across)
    cyclist, cyclist_cells = _record(1, [(10, c) for c in range(10, 14)], (4.0, 0.0))
    out, out_cells = complete_boxes(cyclist, cyclist_cells, WINDOW, _scene(), FREE, PARAMS)
    assert out is cyclist and out_cells is cyclist_cells
    # a car's side seen over 3 m (row 9, columns 10-16: centres x 5.25-8.25, y 4.75), driving
    # +x south of the sensor (10.25, 10.25): along u = x the span 3.0 < 4.4 grows away from
    # the sensor, which lies beyond its middle: u from 8.25 - 4.4 = 3.85, centres 4.25-8.25
    # (columns 8-16); across, w = y from 4.75 - 1.8 = 2.95: centres 3.25-4.75 (rows 6-9)
    side, side_cells = _record(1, [(9, c) for c in range(10, 17)], (4.0, 0.0))
    out, out_cells = complete_boxes(side, side_cells, WINDOW, _scene(), FREE, PARAMS)
    got = {divmod(int(f), WINDOW.cols) for f in out_cells}
    assert got == {(r, c) for r in range(6, 10) for c in range(8, 17)}
    parked, parked_cells = _record(1, [(r, 30) for r in range(19, 23)], (0.0, 0.0), "stopped")
    out, _ = complete_boxes(parked, parked_cells, WINDOW, _scene(), FREE, PARAMS)
    assert out is parked
    car, cells = _record(1, [(r, 30) for r in range(19, 23)], (5.0, 0.0))
    out, _ = complete_boxes(car, cells, WINDOW, _scene(), FREE, BoxParams())
    assert out is car


def test_a_diagonal_car_fills_an_oriented_box() -> None:
    # driving along +x+y; its rear face one cell: (20, 30)... the face must span 1.5 m to be
    # a vehicle: a diagonal face of 4 cells (19,31) (20,30) (21,29) (22,28), across the
    # velocity. Every added cell's centre lies in the box and beyond the face from the sensor
    face = [(19, 31), (20, 30), (21, 29), (22, 28)]
    car, cells = _record(1, face, (3.0, 3.0))
    out, out_cells = complete_boxes(car, cells, WINDOW, _scene(), FREE, PARAMS)
    u = np.array([1.0, 1.0]) / np.sqrt(2)
    centre = lambda rc: np.array([rc[1] + 0.5, rc[0] + 0.5]) * RES  # noqa: E731
    face_u = max(centre(rc) @ u for rc in face)
    added = [divmod(int(f), WINDOW.cols) for f in out_cells[len(face):]]
    assert len(added) > 10
    assert all(face_u - 1e-9 <= centre(rc) @ u <= face_u + 4.4 + 1e-9 for rc in added)


def _random_frame(rng: np.random.Generator):
    """Records of random blobs (moving or stopped, random velocities, some of one cell or
    leaving the window), a scan speaking of a random third of the cells, a window off the
    lattice origin."""
    window = Window(RES, 60, 50, int(rng.integers(-30, 30)), int(rng.integers(-30, 30)))
    n = int(rng.integers(1, 8))
    taken: set[int] = set()
    records, pieces = np.zeros(n, OBJECT_DTYPE), []
    for k in range(n):
        r0, c0 = int(rng.integers(0, 60)), int(rng.integers(0, 50))
        h, w = int(rng.integers(1, 5)), int(rng.integers(1, 6))
        cells = [r * 50 + c for r in range(r0, min(r0 + h, 60)) for c in range(c0, min(c0 + w, 50))
                 if rng.random() < 0.7 and r * 50 + c not in taken] or []
        taken.update(cells)
        records[k]["track_id"] = k + 1
        records[k]["state"] = OBJECT_STATES["moving" if rng.random() < 0.8 else "stopped"]
        records[k]["cell_count"] = len(cells)
        records[k]["velocity_m_per_s"] = rng.normal(0.0, 4.0, 2) * (rng.random() < 0.9)
        pieces.append(np.array(cells, np.uint32))
    speaks = (rng.random(window.shape) < 0.3).astype(np.float32) * 0.7
    occupied = np.zeros(window.shape, np.float32)
    for f in taken:
        occupied.reshape(-1)[f] = 0.8 if rng.random() < 0.5 else 0.0
    returns = np.where(rng.random(window.shape) < 0.1, 1.0, 0.0).astype(np.float32)
    return records, np.concatenate(pieces), window, (speaks, occupied), returns


def test_the_compiled_boxes_equal_the_per_record_reference() -> None:
    """Same cells in the same order, same records (the centroid within rounding: the
    reference takes numpy's pairwise mean, the compiled pass a sequential one)."""
    from tests.objects import reference_boxes as ref
    changed = 0
    for seed in range(40):
        rng = np.random.default_rng(seed)
        objects, cells, window, speaks, returns = _random_frame(rng)
        returns = returns if rng.random() < 0.5 else None
        params = BoxParams(float(rng.choice([2.0, 4.4, 6.0])), float(rng.choice([1.0, 1.8])),
                           float(rng.choice([0.0, 1.5, 3.0])), float(rng.choice([0.5, 1.0])))
        decision = rng.choice(np.array(list(D.values()), np.uint8), window.shape,
                              p=[0.1, 0.6, 0.05, 0.1, 0.05, 0.05, 0.05])
        new, new_cells = complete_boxes(objects, cells, window, speaks, decision, params,
                                        returns=returns)
        old, old_cells = ref.complete_boxes(objects, cells, window, speaks, decision, params,
                                            returns)
        assert new_cells.dtype == old_cells.dtype and new_cells.tobytes() == old_cells.tobytes()
        for name in OBJECT_DTYPE.names:
            if name == "centroid_m":
                # float64 sums of at most ~100 centres of |x| < 100 m: the two summation
                # orders differ by ~1e-13 m; 1e-9 m is far below a cell and above that
                assert np.allclose(new[name], old[name], rtol=0, atol=1e-9), seed
            else:
                assert new[name].tobytes() == old[name].tobytes(), (seed, name)
        changed += new is not objects
    assert changed > 10  # the comparison is not vacuous


def test_the_scans_bool_layers_give_the_float_layers_boxes() -> None:
    """The runner gives the boxes bool layers (:func:`scan_cells`: the cells where
    m({F}) > 0 or m({O}) > 0, and heights > 0) instead of the sensor grid's float32 ones: the
    boxes read both as ``> 0``, so every record and cell is the same (the float path is the
    one checked against the reference above); the layers themselves are numpy's compares."""
    from evperc.objects.stage import scan_cells
    changed = 0
    for seed in range(30):
        rng = np.random.default_rng(100 + seed)
        objects, cells, window, (free, occupied), heights = _random_frame(rng)
        # a return's height above the ground, or +inf (a planar scan's cells); 0: no return
        heights = np.where(heights > 0, rng.choice([0.4, np.inf], window.shape), 0.0
                           ).astype(np.float32)
        returns = heights if rng.random() < 0.7 else None
        decision = rng.choice(np.array(list(D.values()), np.uint8), window.shape,
                              p=[0.1, 0.6, 0.05, 0.1, 0.05, 0.05, 0.05])
        speaks, held_returns, occupied_now = scan_cells(free, occupied, returns)
        assert np.array_equal(speaks, (free > 0) | (occupied > 0))
        assert np.array_equal(occupied_now, occupied > 0)
        assert (held_returns is None) == (returns is None)
        assert returns is None or np.array_equal(held_returns, returns > 0)
        floats = complete_boxes(objects, cells, window, (free, occupied), decision, PARAMS,
                                returns=returns)
        bools = complete_boxes(objects, cells, window, speaks, decision, PARAMS,
                               returns=held_returns)
        assert floats[1].tobytes() == bools[1].tobytes(), seed
        assert floats[0].tobytes() == bools[0].tobytes(), seed
        changed += floats[0] is not objects
    assert changed > 10  # boxes were added: the comparison is not vacuous


def test_a_run_adds_box_cells_to_its_moving_records(tmp_path) -> None:
    """Through `evperc run`: the street drive's crossing object (a 2 m square, seen at its
    2 m wide south face: a vehicle by the rear test) with and without boxes. The tracker does
    not see the boxes (same tracks, ids and states); the box run's records hold every cell
    of the other run's and more, all decided `moving`."""
    import evperc
    from evperc.config import load_config
    from evperc.runner import RunRequest, run
    from tests.e2e.scenes import write_street_drive
    drive = write_street_drive(tmp_path / "street.mcap", n_scans=30)
    runs = []
    for name, length in (("boxes", 4.4), ("none", 0.0)):
        config = load_config(overrides={"grid.window_size_m": 40.0,
                                        "objects.box_length_m": length})
        run(RunRequest(log_path=drive, out_dir=tmp_path / name, config=config))
        runs.append(list(evperc.load(tmp_path / name).frames))
    grown = 0
    for with_box, without in zip(*runs, strict=True):
        a, b = with_box.objects, without.objects
        assert a["track_id"].tolist() == b["track_id"].tolist()
        assert a["state"].tolist() == b["state"].tolist()
        la, lb = with_box.object_labels(), without.object_labels()
        for record in a:
            cells_a, cells_b = la == record["track_id"], lb == record["track_id"]
            assert not (cells_b & ~cells_a).any()
            extra = cells_a & ~cells_b
            if record["state"] == OBJECT_STATES["moving"] and extra.any():
                grown += 1
                assert (with_box.decision[extra] == D["moving"]).all()
    assert grown > 0, "some moving record got box cells"
