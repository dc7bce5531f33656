"""The `evperc run` driver: log + map in, output directory out. Reads like its table of
contents: open inputs, geo-reference, then for each scan sensor grid → fusion step →
decision → write. The maths lives in :mod:`evperc.fusion.twin` and the modules it calls."""

from __future__ import annotations

import logging
import math
import shutil
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from evperc.config import preset_for_layers, with_preset
from evperc.errors import GeoreferenceError, OutputError, PoseError
from evperc.fusion.fused import (
    StoredOutputs,
    count_codes,
    focal_sets,
    fused_step,
    vacuous_flags,
    vacuous_state,
)
from evperc.fusion.gate import GateState, gate_step
from evperc.fusion.twin import CLASSES, DECISION_CODES, FusionParams
from evperc.geo import georef as georef_mod
from evperc.geo.crs import working_crs
from evperc.geo.maps import MapData, check_overlap, load_map, load_map_cached
from evperc.geo.prior import CONTEXT_BUILDING, PriorRasteriser
from evperc.geo.window import Window
from evperc.logs import message_log
from evperc.logs.factory import open_log
from evperc.logs.scan import PosedScan
from evperc.logs.transforms import extrinsic_matrix
from evperc.objects.backfill import Backfill, HeldFrame, backfill_frames, candidates
from evperc.objects.boxes import BoxParams, VehicleBoxes
from evperc.objects.clusters import JOINS_ANY
from evperc.objects.footprint import FootprintParams, FootprintState, complete_footprints
from evperc.objects.point_labels import LABELS_DIR, point_labels, write_labels
from evperc.objects.stage import (
    ObjectStage,
    fill_moving,
    fills_decision,
    moving_needs_object,
    objects_enabled,
    scan_cells,
    small_moving_cells,
    unfill_small,
    unfill_unconfirmed,
)
from evperc.objects.support import SmallGroupSupport, SupportParams
from evperc.objects.tracking import TrackerState
from evperc.objects.unmapped import UnmappedCue, UnmappedParams, UnmappedState, unmapped_enabled
from evperc.output.manifest import read_manifest
from evperc.output.npz import write_npz
from evperc.output.objects import OBJECT_STATES, moving_object_cells, record_cells
from evperc.output.quantise import dequantise, dequantise_planar
from evperc.output.writer import HeldLayers, RunWriter, check_output_dir
from evperc.plumbing import fusion_threads, keep_freed_memory, prefetched
from evperc.progress import bar as progress_bar
from evperc.sensor import SensorParams, sensor_grid
from evperc.sensor.map_fit import MapFit, fit_map
from evperc.sensor.pose_fit import PoseFit, check_poses
from evperc.warm import WarmSpec, warm_up

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunRequest:
    """What the user asked `evperc run` to do."""

    log_path: Path
    out_dir: Path
    config: dict[str, Any]
    map_path: Path | None = None
    roads_path: Path | None = None
    overwrite: bool = False
    start_s: float | None = None
    end_s: float | None = None
    every: int = 1
    lidar_topic: str | None = None
    pose_topic: str | None = None
    point_labels: bool = False  # also write OUT/labels/NNNNNN.label (objects.point_labels)
    #: the user's --config file, under whose keys a sensor preset goes (``sensor_preset``)
    config_path: Path | None = None
    #: take the shipped preset tuned for the log's lidar (its layers as the reader reads
    #: them, :func:`evperc.config.preset_for_layers`) under ``config_path``'s keys, once the log
    #: is open (`evperc run` and `evperc batch` without --preset); the pipeline's request has
    #: it done (False, ``config`` and ``preset`` set)
    sensor_preset: bool = False
    #: the shipped preset whose keys ``config`` holds (given with --preset, or chosen from the
    #: lidar's layers); None: none
    preset: str | None = None


@dataclass(frozen=True)
class FrameInputs:
    """One scan made ready for the fusion step (:meth:`Pipeline.prepare`)."""

    stamp_ns: int
    pose: np.ndarray              # x_m, y_m, yaw_rad of the sensor in the working CRS
    window: Window
    free: np.ndarray | None       # sensor grid m({F}), float32 window.shape (None: not yet)
    occupied: np.ndarray | None   # sensor grid m({O})
    labels: np.ndarray | None     # map context labels, None without a map
    #: cells within map.building_margin_m of a building (bool), None without map or margin
    near_building: np.ndarray | None
    seconds: dict[str, float]     # time spent preparing it, per stage
    scan: PosedScan | None = None  # the scan whose sensor grid is still to compute
    t_crs: np.ndarray | None = None  # its sensor pose in the working CRS
    #: (scan, t_crs, point kinds) kept for the per-point labels (``--point-labels``)
    labelling: tuple[PosedScan, np.ndarray, np.ndarray] | None = None
    #: cells holding any obstacle return of the scan (bool), with objects.cluster_on =
    #: "all_returns" only (:func:`evperc.sensor.sensor_grid`, ``hits_out``)
    hits: np.ndarray | None = None
    #: each cell's highest return above the local ground (float32), with
    #: objects.moving_min_height_m only (:func:`evperc.sensor.sensor_grid`, ``heights_out``)
    heights: np.ndarray | None = None
    #: each cell's sums of its obstacle returns' offsets from its centre and their count
    #: (float32 (rows, cols, 3)), with objects.centroid = "returns" only
    #: (:func:`evperc.sensor.sensor_grid`, ``sums_out``)
    return_sums: np.ndarray | None = None
    #: with the object stage: bool layers of the cells the scan speaks of, of those holding
    #: a return and of those it marks occupied (:func:`evperc.objects.stage.scan_cells`),
    #: for the clusters, the footprints, the boxes and the backfill
    scan_cells: tuple[np.ndarray, np.ndarray | None, np.ndarray] | None = None
    #: with sensor.ground_chain_gap_road_reach_m: the map context with the roads widened by
    #: that reach, for the sensor grid's capped ground (None: ``labels``)
    cap_labels: np.ndarray | None = None


def geo_reference(reader: Any, config: dict[str, Any], need_crs: bool
                  ) -> georef_mod.Georeference | None:
    """Place the log's world frame in the working CRS: poses_crs, else origin, else GNSS.

    Returns ``None`` (work in the log's own frame) when no map is used and nothing geo-
    references the log."""
    inp = config["input"]
    if inp["poses_crs"]:
        return georef_mod.identity(working_crs(inp["poses_crs"], None, key="input.poses_crs"))
    if not (math.isnan(inp["origin_lat_deg"]) or math.isnan(inp["origin_lon_deg"])):
        lonlat = (inp["origin_lon_deg"], inp["origin_lat_deg"])
        crs = working_crs(config["map"]["crs"], lonlat)
        return georef_mod.from_origin(inp["origin_lat_deg"], inp["origin_lon_deg"],
                                      inp["origin_heading_deg"], crs)
    spans = reader.gnss_spans()
    georef = _from_gnss(reader, config, spans) if len(spans) > 1 else None
    if georef is None:  # a short log, or a sparse GNSS topic the spans missed: every fix
        georef = _from_gnss(reader, config, [(None, None)])
    if georef is not None:
        return georef
    if need_crs:
        raise GeoreferenceError(
            f"{reader.path}: poses are in a local frame and the log has no GNSS topic; set "
            "input.origin_lat_deg / origin_lon_deg / origin_heading_deg (or input.poses_crs) "
            "in a --config file, or run with --no-map")
    return None


def _from_gnss(reader: Any, config: dict[str, Any],
               spans: list[tuple[int | None, int | None]]) -> georef_mod.Georeference | None:
    """The rigid fit of the fixes logged in ``spans`` (``reader.gnss_spans()``) to the poses
    at their stamps. None if they hold no fix — or, for spans of a long log, fewer usable
    fixes than spans (a GNSS topic too sparse for them: the caller reads every fix)."""
    sampled = len(spans) > 1
    one_read = _read_once(reader, spans)
    if one_read:  # each span's fixes and poses in one read, placed before the next is read
        in_spans, placed = [], []
        antenna = None
        for a, b in one_read:
            span = reader.gnss_span(a, b)
            in_spans.append(span.fixes)
            if len(span.fixes) and antenna is None:
                antenna = reader.gnss_antenna_frame()
            placed.append(span.positions(antenna)[:, :2] if len(span.fixes)
                          else np.empty((0, 2)))
    else:
        in_spans = [reader.gnss_fixes(a, b) for a, b in spans]
    fixes = np.concatenate(in_spans)
    if len(fixes) < len(spans):
        return None
    crs = working_crs(config["map"]["crs"], (float(fixes[0, 2]), float(fixes[0, 1])))
    world_xy = (np.concatenate(placed) if one_read
                else _fix_positions(reader, in_spans, reader.gnss_antenna_frame()))
    if np.isnan(world_xy).all():
        log.info("%s: GNSS frame not reachable through the poses; fitting the fixes to the "
                 "lidar positions", reader.path)
        world_xy = _fix_positions(reader, in_spans, None)
    valid = ~np.isnan(world_xy).any(axis=1)  # fixes outside the pose span
    if sampled and valid.sum() < len(spans):
        return None
    if sampled:
        log.info("%s: a long log: its GNSS fixes read in %d spans of %.0f s spread over it",
                 reader.path, len(spans), (spans[0][1] - spans[0][0]) * 1e-9)
    return georef_mod.from_gnss(world_xy[valid], fixes[valid][:, [2, 1]], crs)


def _read_once(reader: Any, spans: list[tuple[int | None, int | None]]
               ) -> list[tuple[int, int]]:
    """The spans whose fixes and poses :func:`_from_gnss` reads together
    (``reader.gnss_span``, one span's poses held at a time): a long log's spans (a few
    seconds each), or a whole log no longer than they are together (``[(None, None)]`` of a
    log of at most 32 s); none (a
    read of the fixes, then one of the poses around them, streamed) for a long log read
    whole — a source that cannot seek, or a GNSS topic too sparse for the spans — and for a
    reader without ``gnss_span`` (a KITTI folder)."""
    if not callable(getattr(reader, "gnss_span", None)):
        return []
    if len(spans) > 1:
        return [(int(a), int(b)) for a, b in spans]  # type: ignore[arg-type]
    start, end = reader.start_ns, reader.end_ns
    if (start is None or end is None
            or end - start > message_log.GNSS_SPANS * message_log.GNSS_SPAN_S * 1e9):
        return []
    return [(int(start), int(end) + 1)]


def _fix_positions(reader: Any, in_spans: list[np.ndarray], frame: str | None) -> np.ndarray:
    """(K, 2) world position of ``frame`` (None: the lidar) at the stamps of the fixes of
    each span in turn (a span's poses read around its own fixes only, not over the log)."""
    return np.concatenate([reader.positions_at(f[:, 0].astype(np.int64), frame=frame)[:, :2]
                           for f in in_spans])


def pose_xy_yaw(t_crs_sensor: np.ndarray) -> np.ndarray:
    return np.array([t_crs_sensor[0, 3], t_crs_sensor[1, 3],
                     math.atan2(t_crs_sensor[1, 0], t_crs_sensor[0, 0])])


CHECKPOINT_GLOB = "checkpoint_*.npz"


class StageClock:
    """Wall time and the calling thread's CPU time per pipeline stage, summed over frames (for
    the run summary and benchmarks).

    ``clock.lap("sensor")`` charges the time since the previous lap to ``sensor``. The wall
    time includes the moments the thread waited for a core (three busy threads share two
    cores); the CPU time (``cpu_seconds``, ``time.thread_time``) does not."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.cpu_seconds: dict[str, float] = {}
        self.restart()

    def restart(self) -> None:
        self._last = time.perf_counter()
        self._last_cpu = time.thread_time()

    def lap(self, stage: str) -> None:
        now, now_cpu = time.perf_counter(), time.thread_time()
        self.seconds[stage] = self.seconds.get(stage, 0.0) + now - self._last
        self.cpu_seconds[stage] = self.cpu_seconds.get(stage, 0.0) + now_cpu - self._last_cpu
        self._last, self._last_cpu = now, now_cpu

    def add(self, seconds: dict[str, float]) -> None:
        """Charge time measured elsewhere (another thread) to its stages."""
        for stage, value in seconds.items():
            self.seconds[stage] = self.seconds.get(stage, 0.0) + value

    def per_frame_ms(self, frames: int, cpu: bool = False) -> dict[str, float]:
        """Milliseconds per frame by stage: wall time, or with ``cpu`` the lapping thread's
        CPU time (the stages lapped by it only)."""
        seconds = self.cpu_seconds if cpu else self.seconds
        return {k: round(1e3 * v / max(frames, 1), 3) for k, v in seconds.items()}


def checkpoint_path(out_dir: Path, frames: int) -> Path:
    """The state after ``frames`` frames; the one matching the manifest is used on resume."""
    return out_dir / f"checkpoint_{frames:09d}.npz"


@dataclass
class FusionState:
    """Everything the loop carries from one scan to the next; saved with every chunk so an
    interrupted run resumes bit-identically (``evperc run --resume``).

    ``pg`` (planar ``(32, rows, cols)`` masses) and ``zeta`` are circular buffers: window
    cell ``(r, c)`` is buffer cell ``((r + offset[0]) % rows, (c + offset[1]) % cols)``
    (:func:`evperc.fusion.fused.fused_step`); ``flags`` marks the exactly vacuous cells and
    ``focal`` holds each cell's focal sets (bitmask), both derived from ``pg`` on load;
    ``gate`` is the motion gate's state (:mod:`evperc.fusion.gate`), in the same circular
    buffer."""

    window: Window | None = None
    pg: np.ndarray | None = None
    zeta: np.ndarray | None = None
    flags: np.ndarray | None = None
    focal: np.ndarray | None = None
    gate: GateState | None = None
    offset: tuple[int, int] = (0, 0)
    prev_ns: int | None = None
    scan_index: int = -1          # position in the log's scan stream of the last frame
    frames: int = 0
    decision_counts: np.ndarray = field(
        default_factory=lambda: np.zeros(len(DECISION_CODES), dtype=np.int64))
    #: the object tracker's state (None: objects off, or no frame yet)
    tracks: TrackerState | None = None
    #: the unmapped cue's per-cell state, in the circular buffer (None: cue off, or no frame)
    unmapped: UnmappedState | None = None
    #: the footprint completion's per-track history (None: off, or no frame yet)
    footprints: FootprintState | None = None
    #: the small groups' support: the last frames' motion cells (None: off, or no frame yet)
    support: SmallGroupSupport | None = None

    @staticmethod
    def fresh(window: Window) -> FusionState:
        """Every cell vacuous, ζ = 0."""
        state = FusionState()
        state.allocate(window.shape)
        state.window = window
        return state

    def allocate(self, shape: tuple[int, int]) -> None:
        """Vacuous buffers for a window of ``shape`` (the first :meth:`move_to` keeps them),
        every page written now: the first frame does not fault 20 MB in (a 200 m window)."""
        self.pg, self.zeta, self.flags, self.focal = vacuous_state(shape)
        self.gate = GateState.fresh(shape)

    def move_to(self, window: Window) -> tuple[int, int]:
        """Make ``window`` the state's window; returns the shift ``(dr, dc)`` that
        :func:`evperc.fusion.fused.fused_step` reads the previous cells with. The first window
        starts vacuous; a moved one keeps its cells in the circular buffers (the offset
        follows the move)."""
        shift = (0, 0)
        if self.window is None:
            if self.pg is None or self.pg.shape[1:] != window.shape:
                self.allocate(window.shape)
            self.offset = (0, 0)
        elif window != self.window:
            shift = (window.row0 - self.window.row0, window.col0 - self.window.col0)
            self.offset = ((self.offset[0] + shift[0]) % window.rows,
                           (self.offset[1] + shift[1]) % window.cols)
        self.window = window
        return shift

    def snapshot(self, into: FusionState | None = None) -> FusionState:
        """A copy that later frames do not change (saved by the writer thread); reuses the
        buffers of ``into`` (an earlier snapshot already saved) when they fit."""
        if into is None or into.pg is None or into.pg.shape != self.pg.shape:
            into = FusionState(pg=np.empty_like(self.pg), zeta=np.empty_like(self.zeta))
        np.copyto(into.pg, self.pg)
        np.copyto(into.zeta, self.zeta)
        if into.gate is None or into.gate.ever.shape != self.gate.ever.shape:
            into.gate = self.gate.copy()
        else:
            np.copyto(into.gate.times, self.gate.times)
            np.copyto(into.gate.ever, self.gate.ever)
        into.window, into.offset, into.prev_ns = self.window, self.offset, self.prev_ns
        into.scan_index, into.frames = self.scan_index, self.frames
        into.decision_counts = self.decision_counts.copy()
        into.tracks = self.tracks.copy() if self.tracks is not None else None
        into.unmapped = self.unmapped.copy() if self.unmapped is not None else None
        into.footprints = self.footprints.copy() if self.footprints is not None else None
        into.support = self.support.copy() if self.support is not None else None
        return into

    def save(self, path: Path) -> None:
        """The circular buffers as they are, with their offset (stored, not deflated: the
        writer thread's time matters more than the checkpoint's size)."""
        w = self.window
        arrays = {"pg": self.pg, "zeta": self.zeta, "gate_times": self.gate.times,
                  "gate_ever": self.gate.ever,
                  "offset": np.array(self.offset, dtype=np.int64),
                  "window": np.array([w.rows, w.cols, w.row0, w.col0], dtype=np.int64),
                  "resolution_m": np.float64(w.resolution_m),
                  "prev_ns": np.int64(self.prev_ns), "scan_index": np.int64(self.scan_index),
                  "frames": np.int64(self.frames), "decision_counts": self.decision_counts}
        if self.tracks is not None:
            arrays.update(self.tracks.to_arrays())
        if self.unmapped is not None:
            arrays.update(self.unmapped.to_arrays())
        if self.footprints is not None:
            arrays.update(self.footprints.to_arrays())
        if self.support is not None:
            arrays.update(self.support.to_arrays())
        write_npz(path, arrays, compress=False)

    @staticmethod
    def load(path: Path) -> FusionState:
        try:
            with np.load(path) as npz:
                rows, cols, row0, col0 = (int(v) for v in npz["window"])
                pg, zeta = npz["pg"], npz["zeta"]
                if pg.shape != (32, rows, cols):
                    raise ValueError(f"state of shape {pg.shape}, expected (32, {rows}, {cols})")
                offset = tuple(int(v) for v in npz["offset"])
                if not (0 <= offset[0] < rows and 0 <= offset[1] < cols):
                    raise ValueError(f"offset {offset} outside the {rows} x {cols} window")
                gate = GateState(npz["gate_times"], npz["gate_ever"])
                if gate.times.shape != (3, rows, cols) or gate.ever.shape != (rows, cols):
                    raise ValueError(f"gate state of shape {gate.times.shape}")
                return FusionState(
                    window=Window(float(npz["resolution_m"]), rows, cols, row0, col0),
                    pg=pg, zeta=zeta, flags=vacuous_flags(pg, zeta), focal=focal_sets(pg),
                    gate=gate,
                    offset=offset,
                    prev_ns=int(npz["prev_ns"]),
                    scan_index=int(npz["scan_index"]), frames=int(npz["frames"]),
                    decision_counts=npz["decision_counts"],
                    tracks=TrackerState.from_arrays(npz),
                    unmapped=UnmappedState.from_arrays(npz),
                    footprints=FootprintState.from_arrays(npz),
                    support=SmallGroupSupport.from_arrays(npz))
        except (OSError, ValueError, KeyError) as err:
            raise OutputError(f"{path}: missing or unreadable checkpoint ({err}); rerun "
                              "without --resume and with --overwrite") from err


class Pipeline:
    """Inputs opened and checked once; :meth:`step` turns one posed scan into one frame."""

    def __init__(self, request: RunRequest, reuse_map: bool = False) -> None:
        config = request.config
        self.reader = open_log(
            request.log_path,
            lidar_topic=request.lidar_topic or config["input"]["lidar_topic"] or None,
            pose_topic=request.pose_topic or config["input"]["pose_topic"] or None,
            gnss_topic=config["input"]["gnss_topic"] or None,
            world_frame=config["input"]["world_frame"] or None,
            extrinsic=extrinsic_matrix(**config["input"]["extrinsic"]),
            max_pose_gap_s=config["input"]["max_pose_gap_s"])
        #: the request as run: with ``sensor_preset``, its config holds the preset's keys
        self.request = request = self._sensor_preset(request)
        config = request.config
        self.georef = geo_reference(self.reader, config, need_crs=request.map_path is not None)
        self.crs_name = self.georef.crs.to_string() if self.georef is not None else "local"
        self.resolution = config["grid"]["cell_size_m"]
        self.window_size = config["grid"]["window_size_m"]
        self.sensor_params = SensorParams.from_config(config["sensor"], self.resolution)
        self.map_data: MapData | None = None
        #: map.fit_to_scans: the map's fit to the first scans (evperc.sensor.map_fit)
        self.map_fit: MapFit | None = None
        self.rasteriser: PriorRasteriser | None = None
        self.near_rasteriser: PriorRasteriser | None = None
        #: the roads widened by sensor.ground_chain_gap_road_reach_m (method.md §3)
        self.reach_rasteriser: PriorRasteriser | None = None
        if request.map_path is not None:
            read = load_map_cached if reuse_map else load_map
            map_data = read(request.map_path, request.roads_path, config_map=config["map"])
            self.map_data = map_data.to_crs(self.georef.crs)
            if config["map"]["fit_to_scans"]:
                self.map_data, self.map_fit = self._fit_map(self.map_data)
            tile = config["map"]["tile_size_cells"]
            self.rasteriser = PriorRasteriser(self.map_data, self.resolution, tile)
            margin = config["map"]["building_margin_m"]
            # the buildings widened by the margin close the motion gate (method.md §4a);
            # the prior keeps the mapped outlines
            self.near_rasteriser = (PriorRasteriser(
                replace(self.map_data, roads=self.map_data.roads[:0]), self.resolution, tile,
                building_margin_m=margin, inner=self.rasteriser) if margin > 0 else None)
            sensor = config["sensor"]
            reach = sensor["ground_chain_gap_road_reach_m"]
            if (reach > 0 and sensor["ground_chain"] and sensor["ground_chain_gap_m"] > 0
                    and sensor["ground_chain_gap_road_only"]):
                self.reach_rasteriser = PriorRasteriser(
                    replace(self.map_data, buildings=self.map_data.buildings[:0]),
                    self.resolution, tile, road_margin_m=reach)
        self.betas = (config["map"]["beta_building"], config["map"]["beta_road"],
                      config["map"]["beta_other"])
        self.params = FusionParams.from_config(config)
        self.fusion_threads = fusion_threads(config["fusion"]["threads"])
        self._overlap_checked = False
        self.clock = StageClock()
        #: frames whose sensor grid the fusion thread computed (:meth:`inputs`, ``defer``)
        self.sensor_grids_in_step = 0
        self.pose_fit: PoseFit | None = None  # check_poses
        self._gate_buffer: np.ndarray | None = None
        probe = Window.centred_on(0.0, 0.0, self.window_size, self.resolution)
        self.objects = (ObjectStage(config, probe.shape) if objects_enabled(config) else None)
        self.fill_moving = fills_decision(config)
        #: objects.moving_needs_object: a cell stays moving only in a moving object
        self.moving_needs_object = moving_needs_object(config)
        self.footprint = FootprintParams.from_config(config)
        #: objects.small_support_frames: small moving groups need company (support.py)
        self.support_params = (SupportParams.from_config(config) if self.moving_needs_object
                               else SupportParams())
        self.boxes = VehicleBoxes(BoxParams.from_config(config))
        #: objects.backfill_frames: frames are handed to the output this many frames late,
        #: with the tracks reported moving since filled in (evperc.objects.backfill); 0 = off
        self.backfill_frames = backfill_frames(config)
        #: objects.cluster_on = "all_returns": clusters grow through the cells holding any
        #: obstacle return of the scan, not only those the sensor model marks occupied
        self.cluster_on = (config["objects"].get("cluster_on", "first_returns")
                           if self.objects is not None else "first_returns")
        self.cluster_all_returns = self.cluster_on != "first_returns"
        #: objects.centroid = "returns": the sensor grid also gives each cell's return sums,
        #: with the heights in the same pass (valid where a cell's height is > 0, so the
        #: sums' block is never cleared: sensor_grid's ``sums_out``)
        self.return_sums = self.objects is not None and self.objects.needs_return_sums
        #: objects.moving_min_height_m / isolated_min_height_m, the vehicle boxes and the
        #: return sums: the sensor grid also gives each cell's highest return
        self.top_heights = self.objects is not None and (self.objects.needs_heights
                                                         or self.boxes.enabled
                                                         or self.return_sums)
        #: the return sums' arrays the object stage is done with, for the next sensor grids
        #: (1.9 MB a frame on a 400 × 400 window: reused, not faulted in afresh each frame);
        #: a deque's append and pop are atomic, and the decode thread pops while the fusion
        #: thread appends
        self._spare_sums: deque[np.ndarray] = deque()
        self.unmapped = (UnmappedCue(UnmappedParams.from_config(config), probe.shape,
                                     self.resolution) if unmapped_enabled(config) else None)
        self._warm_up()

    def _warm_up(self) -> None:
        """Load (or compile, on a fresh install: in several processes) the numba kernels of
        the frame loop now, so that start-up is not charged to the first frame
        (:mod:`evperc.warm`)."""
        warm_up(WarmSpec(self.request.config, has_map=self.rasteriser is not None))

    def meta(self) -> dict[str, Any]:
        """Manifest entries that describe the run (docs/output-format.md)."""
        probe = Window.centred_on(0.0, 0.0, self.window_size, self.resolution)
        request = asdict(self.request)
        request.pop("config")
        request.pop("overwrite")
        # absolute input paths: `evperc run --resume` and `render` work from any directory
        # (the output directory itself is where the manifest is found, so it may move)
        request.pop("out_dir")
        for key in ("log_path", "map_path", "roads_path", "config_path"):
            if request[key] is not None:
                request[key] = Path(request[key]).absolute()
        return {"decision_codes": DECISION_CODES, "classes": list(CLASSES),
                "crs": self.crs_name, "resolution_m": self.resolution, "rows": probe.rows,
                # the log's world frame in the working CRS (None: the run is in the log's frame)
                "T_crs_world": (self.georef.T_crs_world.tolist() if self.georef is not None
                                else None),
                "cols": probe.cols, "log": str(request["log_path"]),
                "map": str(request["map_path"]) if request["map_path"] else None,
                "roads": str(request["roads_path"]) if request["roads_path"] else None,
                "request": {k: (str(v) if isinstance(v, Path) else v)
                            for k, v in request.items()},
                # docs/output-format.md, "Per-point labels"
                "point_labels": ({"dir": LABELS_DIR, "convention": "SemanticKITTI-MOS",
                                  "codes": {"unknown": 0, "static": 9, "moving": 251},
                                  "naming": "the scan's file number" if self.request.point_labels
                                  and hasattr(self.reader, "numbers") else "frame index"}
                                 if self.request.point_labels else None),
                # how well the log's poses fit its scans (None: not checked)
                "pose_fit": self.pose_fit.summary() if self.pose_fit is not None else None,
                "map_fit": self.map_fit.summary() if self.map_fit is not None else None}

    def _fit_map(self, map_data: MapData) -> tuple[MapData, MapFit | None]:
        """``map_data`` moved to fit the span's first scans (:func:`evperc.sensor.map_fit.fit_map`;
        ``map.fit_to_scans``), and the fit, said in one line."""
        scans = self.scans(-1)
        try:
            moved, fit = fit_map(map_data, (scan for _, scan in scans), self.georef.apply,
                                 self.sensor_params)
        finally:
            scans.close()
        where = self.request.map_path
        if fit is None:
            log.info("%s: used as it is: the first scans' returns meet too few of its building "
                     "outlines to fit it to them (map.fit_to_scans)", where)
        elif fit.moved:
            log.info("%s: moved %.2f m east, %.2f m north to fit the scans (%d returns of %d "
                     "scans on its outlines: %.0f %% -> %.0f %%)", where, *fit.offset_m,
                     fit.returns, fit.scans, 100 * fit.share_at_map, 100 * fit.share_best)
        else:
            log.info("%s: fits the scans (%d returns of %d scans, %.0f %% on its outlines; "
                     "the best offset, %.2f m east, %.2f m north, not worth a move)", where,
                     fit.returns, fit.scans, 100 * fit.share_at_map, *fit.best_m)
        return moved, fit

    def check_poses(self) -> PoseFit | None:
        """Whether the log's poses fit its scans (:func:`evperc.sensor.pose_fit.check_poses`
        on the requested span's first scans), kept in ``pose_fit``. ``input.pose_check``:
        "warn" logs a misfit, "error" stops the run with it (:class:`PoseError`), "off"
        does not check."""
        mode = self.request.config["input"].get("pose_check", "warn")
        if mode == "off":
            return None
        scans = self.scans(-1)
        try:
            self.pose_fit = check_poses((scan for _, scan in scans), self.sensor_params)
        finally:
            scans.close()
        if self.pose_fit is not None and self.pose_fit.misfit:
            message = self.pose_fit.message(str(self.request.log_path))
            if mode == "error":
                raise PoseError(f"{message} (input.pose_check = \"error\")")
            log.warning("%s", message)
        return self.pose_fit

    def _sensor_preset(self, request: RunRequest) -> RunRequest:
        """``request`` with ``sensor_preset`` done: the shipped preset tuned for the log's
        lidar (:func:`evperc.config.preset_for_layers`: its layers as the log's reader reads them —
        a KITTI folder's HDL-64E, a message log's ``ring`` field or organised rows) put under
        the user's --config keys, and said in one line; the config unchanged when the layers
        are unknown or no preset is tuned for them. Read from the run's own reader, before any
        key beyond ``[input]`` (which no sensor preset sets) is read."""
        if not request.sensor_preset:
            return request
        layers = self.reader.sensor_layers()
        name = None if layers is None else preset_for_layers(layers[0])
        if name is None:
            return replace(request, sensor_preset=False)
        under = (f", under {request.config_path}'s keys" if request.config_path is not None
                 else "")
        log.info("%s: a %d-layer lidar (%s): running with --preset %s, tuned for such "
                 "scanners%s (--preset none: the defaults alone)", request.log_path,
                 layers[0], layers[1], name, under)
        return replace(request, sensor_preset=False, preset=name,
                       config=with_preset(request.config, name, request.config_path))

    def warm_up_inputs(self) -> bool:
        """Read and prepare the first scan of the requested span, and drop it: the one-off
        costs of the first frame (opening the log's index, building the message decoders,
        rasterising the map tiles around the first pose: ~26 ms on workload (a)) are paid
        here, with the rest of the start-up, not by the first frame. False if the span has
        no scan to fuse (``reader.stats`` then says why)."""
        scans = self.scans(-1)
        try:
            first = next(scans, None)
        finally:
            scans.close()
        if first is not None:
            self.prepare(first[1])
        return first is not None

    def scans(self, after_index: int) -> Any:
        """``(index, scan)`` of the scans to fuse: the requested time span, every N-th,
        after ``after_index`` (resume)."""
        r = self.request
        start = self.reader.start_ns
        start_ns = None if r.start_s is None else start + int(r.start_s * 1e9)
        end_ns = None if r.end_s is None else start + int(r.end_s * 1e9)
        for index, scan in enumerate(self.reader.scans(start_ns=start_ns, end_ns=end_ns)):
            if not plausible_pose(scan.T_world_sensor):  # a damaged pose in a readable log
                stats = self.reader.stats
                stats["pose_out_of_range"] = stats.get("pose_out_of_range", 0) + 1
                continue
            if index > after_index and index % r.every == 0:
                yield index, scan

    def expected_frames(self) -> int:
        """Frames the run will have, from the log's summary (its lidar message count, the
        share of the log's time span requested, every N-th): the progress bar's total, an
        estimate where scans are skipped or the span cuts the log."""
        r = self.request
        scans = self.reader.scan_count
        length = max(self.reader.end_ns - self.reader.start_ns, 1)
        start = 0 if r.start_s is None else min(max(int(r.start_s * 1e9), 0), length)
        end = length if r.end_s is None else min(max(int(r.end_s * 1e9), start), length)
        return math.ceil(round(scans * (end - start) / length) / r.every)

    def prepare(self, scan: PosedScan, sensor: bool = True) -> FrameInputs:
        """What the fusion step needs from one scan, which does not depend on the fusion
        state: pose, window, sensor grid (method.md §3; left to :meth:`sensor_grid` unless
        ``sensor``) and map labels. The runner calls this in the decode thread, one or two
        scans ahead of the fusion."""
        t0 = time.perf_counter()
        t_crs = (self.georef.apply(scan.T_world_sensor) if self.georef is not None
                 else scan.T_world_sensor)
        pose = pose_xy_yaw(t_crs)
        window = Window.centred_on(pose[0], pose[1], self.window_size, self.resolution)
        if self.map_data is not None and not self._overlap_checked:
            check_overlap(self.map_data, window.bounds)
            self._overlap_checked = True
        t1 = time.perf_counter()
        labels = self.rasteriser.labels(window) if self.rasteriser is not None else None
        near = (self.near_rasteriser.labels(window) == CONTEXT_BUILDING
                if self.near_rasteriser is not None else None)
        cap_labels = (self.reach_rasteriser.labels(window)
                      if self.reach_rasteriser is not None else None)
        t2 = time.perf_counter()
        inputs = FrameInputs(scan.stamp_ns, pose, window, None, None, labels, near,
                             {"geometry": t1 - t0, "prior": t2 - t1}, scan, t_crs,
                             cap_labels=cap_labels)
        return self.sensor_grid(inputs) if sensor else inputs

    def sensor_grid(self, inputs: FrameInputs) -> FrameInputs:
        """``inputs`` with the sensor grid of its scan (method.md §3)."""
        if inputs.scan is None:
            return inputs
        t0 = time.perf_counter()
        scan = inputs.scan
        kinds = np.empty(len(scan.points), np.uint8) if self.request.point_labels else None
        hits = np.empty(inputs.window.shape, np.bool_) if self.cluster_all_returns else None
        heights = np.empty(inputs.window.shape, np.float32) if self.top_heights else None
        sums = self._sums_block(inputs.window.shape) if self.return_sums else None
        free, occupied = sensor_grid(scan.points, scan.planar, inputs.t_crs, inputs.window,
                                     self.sensor_params, kinds_out=kinds, hits_out=hits,
                                     heights_out=heights, sums_out=sums,
                                     context=(inputs.labels if inputs.cap_labels is None
                                              else inputs.cap_labels))
        cells = scan_cells(free, occupied, heights) if self.objects is not None else None
        seconds = {**inputs.seconds, "sensor": time.perf_counter() - t0}
        labelling = (scan, inputs.t_crs, kinds) if kinds is not None else None
        return replace(inputs, free=free, occupied=occupied, seconds=seconds, scan=None,
                       t_crs=None, labelling=labelling, hits=hits, heights=heights,
                       return_sums=sums, scan_cells=cells, cap_labels=None)

    def _sums_block(self, shape: tuple[int, int]) -> np.ndarray:
        """A float32 ``(*shape, 3)`` array for the sensor grid's return sums: one the object
        stage has handed back (:meth:`_spare`), else a new one. Not cleared: the sensor grid
        writes the sums of the cells holding a return, with the heights (``sums_out`` with
        ``heights_out``), and they are read only there."""
        try:  # both threads make sensor grids: pop, do not test and pop
            sums = self._spare_sums.pop()
        except IndexError:
            sums = None
        return sums if sums is not None and sums.shape == (*shape, 3) else np.empty(
            (*shape, 3), np.float32)

    def _spare(self, sums: np.ndarray | None) -> None:
        """Hand ``sums`` back for the next sensor grids once nothing reads it any more (a
        few are kept: as many as scans are decoded ahead)."""
        if sums is not None and len(self._spare_sums) < 4:
            self._spare_sums.append(sums)

    def inputs(self, after_index: int, defer: threading.Event | None = None
               ) -> Iterator[tuple[int, FrameInputs]]:
        """:meth:`prepare` of each scan of :meth:`scans`; ``seconds["decode"]`` is the time
        spent getting the scan (reading, decompressing and decoding the log up to it).
        ``defer``: while it is set (the fusion thread has no scan waiting for it), the sensor
        grid is left to :meth:`step` — the two threads share the work where this one would
        be the bottleneck."""
        scans = self.scans(after_index)
        while True:
            t0 = time.perf_counter()
            item = next(scans, None)
            if item is None:
                return
            decode_s = time.perf_counter() - t0
            inputs = self.prepare(item[1], sensor=defer is None or not defer.is_set())
            inputs.seconds["decode"] = decode_s
            yield item[0], inputs

    def step(self, state: FusionState, inputs: FrameInputs, out: StoredOutputs
             ) -> dict[str, Any]:
        """Fuse one prepared scan into ``state`` (updated in place); the frame's layers go to
        ``out`` (the writer's chunk buffer); returns the frame's metadata."""
        clock = self.clock
        clock.lap("read")  # waiting for the decode thread (reading, decoding, sensor grid)
        if inputs.free is None:  # left to this thread (Pipeline.inputs)
            inputs = self.sensor_grid(inputs)
            del inputs.seconds["sensor"]  # timed here, by the clock
            clock.lap("sensor")
            self.sensor_grids_in_step += 1
        clock.add(inputs.seconds)  # the decode thread's time, overlapped with this one
        window = inputs.window
        shift = state.move_to(window)
        dt_s = 0.0 if state.prev_ns is None else (inputs.stamp_ns - state.prev_ns) * 1e-9
        state.prev_ns = inputs.stamp_ns
        # the motion gate (a neighbourhood pass of its own), then method.md §5 and §6 in one
        # compiled pass, quantised straight into the chunk buffer; evperc.fusion.twin is the
        # numpy twin it is tested on
        gate = (gate_step(state.gate, inputs.free, inputs.occupied, dt_s, self.params,
                          offset=state.offset, shift=shift, out=self._gate_layer(window.shape),
                          closed=inputs.near_building)
                if self.params.gated else None)
        fused_step(state.pg, state.zeta, inputs.free, inputs.occupied, inputs.labels,
                   self.betas, dt_s, self.params, out=out, flags=state.flags, focal=state.focal,
                   offset=state.offset, shift=shift, threads=self.fusion_threads, gate=gate)
        state.frames += 1
        clock.lap("fusion")
        frame: dict[str, Any] = {"stamp_ns": inputs.stamp_ns, "pose": inputs.pose,
                                 "origin": (window.row0, window.col0)}
        if self.objects is not None:  # clusters and tracks (evperc.objects), from the layers
            if state.tracks is None:
                state.tracks = TrackerState()
            speaks, returns, occupied_now = inputs.scan_cells  # this frame's own layers
            if inputs.hits is not None and self.cluster_on == "all_returns":
                occupied_now |= inputs.hits
            elif inputs.hits is not None:  # "all_returns_join": the hit-only cells join any
                occupied_now = occupied_now.view(np.uint8)
                occupied_now[inputs.hits & (occupied_now == 0)] = JOINS_ANY
            frame["objects"], frame["object_cells"] = self.objects.step(
                state.tracks, out.decision, out.betp[4], out.conflict[0], window,
                inputs.stamp_ns, occupied_now=occupied_now, heights=inputs.heights,
                near_building=inputs.near_building, return_sums=inputs.return_sums,
                sensor_xy=(float(inputs.pose[0]), float(inputs.pose[1])))
            self._spare(inputs.return_sums)  # read by the object stage only
            if self.backfill_frames > 0:  # the backfill's gaps (objects.bridge_gaps), boxes
                frame["occupied_now"] = occupied_now
                frame["speaks"], frame["returns"] = speaks, returns
            if self.footprint.frames > 0:  # motion-compensated footprints (objects/footprint.py)
                if state.footprints is None:
                    state.footprints = FootprintState()
                frame["objects"], frame["object_cells"] = complete_footprints(
                    state.footprints, frame["objects"], frame["object_cells"], window,
                    inputs.stamp_ns, speaks, self.footprint)
            if self.boxes.enabled:  # moving vehicles' far sides (objects/boxes.py)
                frame["objects"], frame["object_cells"] = self.boxes.complete(
                    frame["objects"], frame["object_cells"], window, speaks, out.decision,
                    returns=returns)
            moving_cells = moving_object_cells(frame["objects"], frame["object_cells"])
            if self.fill_moving:  # the moving objects' cells decided moving (method.md §8)
                fill_moving(out.decision, moving_cells)
            if self.objects.moving_min_cells > 0:  # small clusters' moving cells: static
                unfill_small(out.decision, self.objects.small_moving, moving_cells)
                if self.moving_needs_object:  # the small groups left moving: their own rule
                    small, group_of = small_moving_cells(
                        *self.objects.clusterer.groups(), out.decision,
                        self.objects.moving_min_cells, with_groups=True)
                    frame["small_groups"] = small
                    if self.support_params.enabled:  # company in space and time (support.py)
                        if state.support is None:
                            state.support = SmallGroupSupport()
                        motion = (small if moving_cells is None
                                  else np.concatenate([small, moving_cells]))
                        state.support.push(state.frames - 1, window.row0, window.col0,
                                           window.cols, motion)
                        frame["support"] = (state.frames - 1, group_of)
            clock.lap("objects")
        else:
            moving_cells = None
        if self.unmapped is not None:  # decision-level pass (evperc.objects.unmapped)
            if state.unmapped is None:
                state.unmapped = UnmappedState.fresh(window.shape)
            self.unmapped.step(state.unmapped, out.decision, inputs.labels, dt_s,
                               moving_cells=moving_cells, offset=state.offset, shift=shift)
            clock.lap("unmapped")
        frame["window"] = window
        if inputs.labelling is not None:
            scan = inputs.labelling[0]
            frame["labelling"] = (*inputs.labelling, scan.number if scan.number is not None
                                  else state.frames - 1)
        if self.backfill_frames == 0:
            self.finish_frame(state, frame, out.decision)
        return frame

    def finish_frame(self, state: FusionState, frame: dict[str, Any], decision: np.ndarray
                     ) -> None:
        """The passes that read the frame's final ``decision`` (uint8 window layer): its counts
        (added to ``state.decision_counts``) and, with ``--point-labels``, the points' labels
        (``frame["point_labels"]``). Run by :meth:`step`, or with ``objects.backfill_frames``
        when the frame leaves the backfill (:func:`run`)."""
        if self.moving_needs_object:  # the fusion's moving cells no moving object holds
            small = frame.pop("small_groups", None)
            support = frame.pop("support", None)
            if support is not None and small is not None:  # small groups need company
                origin = frame["origin"]
                small = state.support.judge(self.support_params, support[0], *origin,
                                            decision.shape[1], small, support[1])
            unfill_unconfirmed(decision, moving_object_cells(
                frame["objects"], frame["object_cells"]), small)
            self.clock.lap("objects")
        # counted after every pass that changes the decision: the counts match the stored one
        try:
            counts = count_codes(decision, len(state.decision_counts))
        except ValueError as err:  # a bug, not the input's: say which frame, then stop
            raise ValueError(f"the frame stamped {frame['stamp_ns']} ns: {err}") from err
        frame["decision_counts"] = counts
        state.decision_counts += counts
        window = frame.pop("window")
        labelling = frame.pop("labelling", None)
        if labelling is not None:  # a separate pass over the points, after the step
            scan, t_crs, kinds, number = labelling
            labels = point_labels(scan.points, kinds, t_crs, window, decision,
                                  scan.source_count, scan.source_index,
                                  **self._object_reach(frame))
            frame["point_labels"] = (number, labels)
            self.clock.lap("point_labels")

    def _object_reach(self, frame: dict[str, Any]) -> dict[str, Any]:
        """The object-reach arguments of :func:`point_labels` for ``frame`` (its moving
        objects' cells, ``objects.point_reach_cells`` and ``point_height_margin_m``); none
        without an object list or with the reach off."""
        objects = frame.get("objects")
        reach = int(self.request.config.get("objects", {}).get("point_reach_cells", 0))
        if objects is None or reach <= 0 or not self.fill_moving:
            return {}
        moving = [c for c, st in zip(record_cells(objects, frame["object_cells"]),
                                     objects["state"], strict=True)
                  if st == OBJECT_STATES["moving"]]
        return {"moving_objects": moving, "reach_cells": reach,
                "height_margin_m": float(self.request.config["objects"]["point_height_margin_m"])}

    def _gate_layer(self, shape: tuple[int, int]) -> np.ndarray:
        """The gate layer's buffer (one per run, reused every frame)."""
        layer = self._gate_buffer
        if layer is None or layer.shape != shape:
            layer = self._gate_buffer = np.empty(shape, np.uint8)
        return layer


#: a sensor position farther than this from the log's world origin (m) is a damaged pose:
#: more than twice the Earth's circumference, beyond any geo-referenced or local frame
MAX_POSE_M = 1e8


def plausible_pose(T_world_sensor: np.ndarray) -> bool:
    """Whether a scan's pose is finite and its position within :data:`MAX_POSE_M` (a damaged
    pose message can decode to 1e300 m, whose window lies beyond the integer lattice)."""
    T = np.asarray(T_world_sensor)
    return bool(np.isfinite(T).all() and np.abs(T[:3, 3]).max() <= MAX_POSE_M)


def frame_arrays(out: StoredOutputs) -> dict[str, np.ndarray]:
    """The stored layers of a frame as float arrays, interleaved ``(rows, cols, k)`` as
    :func:`evperc.load` gives them (for ``on_frame`` consumers such as live rendering)."""
    return {"masses": dequantise_planar(out.masses()), "betp": dequantise_planar(out.betp),
            "decision": out.decision.copy(), "zeta": dequantise(out.zeta),
            "conflict": dequantise_planar(out.conflict)}


def run(request: RunRequest, resume: bool = False,
        on_frame: Callable[[dict[str, Any]], None] | None = None,
        progress: bool | None = None, reuse_map: bool = False) -> dict[str, Any]:
    """Run the whole pipeline (or continue an interrupted run); returns the summary written
    into the manifest. ``on_frame`` sees every frame's arrays (e.g. to render as it goes);
    ``progress``: show the per-frame bar (``None``: only on a terminal); ``reuse_map``: take
    the map read by the previous run in this process if it is the same
    (:func:`evperc.geo.maps.load_map_cached`; ``evperc batch`` workers). With
    ``request.sensor_preset`` the config the run writes and uses is the pipeline's (the
    preset tuned for the log's lidar under ``request.config_path``'s keys)."""
    started = time.perf_counter()
    keep_freed_memory()
    out_dir = request.out_dir
    if not resume:  # an existing output is refused before any slow work
        check_output_dir(out_dir, request.overwrite)
    pipeline = Pipeline(request, reuse_map=reuse_map)
    request = pipeline.request  # with the sensor preset's keys, if one was chosen
    state = FusionState()
    # the inputs are checked (the first scan read, posed, placed on the map) before the
    # output is created: a run that stops on an input error leaves nothing
    if not pipeline.warm_up_inputs() and not resume:
        raise nothing_fused(request, pipeline.reader.stats)
    if resume:
        writer = RunWriter.resume(out_dir)
        done = writer.manifest["frame_count"]
        if done:
            state = FusionState.load(checkpoint_path(out_dir, done))
    else:
        pipeline.check_poses()  # may stop the run before its output exists
        writer = RunWriter(out_dir, request.config, pipeline.meta(), overwrite=request.overwrite)

    def discard_if_empty() -> None:
        """A new run that fails before its manifest lists a frame leaves no output (there
        is nothing to resume; it would block the corrected run)."""
        if not resume and writer.manifest["frame_count"] == 0:
            shutil.rmtree(out_dir, ignore_errors=True)
    # chunk written -> checkpoint of the state -> manifest: a crash anywhere leaves a
    # checkpoint that matches the manifest; older checkpoints go once a newer one is committed
    # checkpoints are 20 MB on a 200 m window: one every output.checkpoint_frames frames
    spare: list[FusionState | None] = [None]  # the last snapshot, saved before the next one
    last_checkpoint = [state.frames]
    finishing = [False]  # the last chunk needs no checkpoint: close() completes the run
    every = int(request.config["output"].get("checkpoint_frames", 1))  # 1: runs before it

    # objects.backfill_frames: a frame reaches the writer that many frames after it was
    # fused, so the state of a chunk's checkpoint is taken when its last frame is fused
    # (its decision counts when that frame is written); frames not yet written are not in
    # it and are fused again on resume
    backfill = (Backfill.from_config(request.config) if pipeline.backfill_frames > 0
                else None)
    snapshots: dict[int, FusionState] = {}
    first_frame = state.frames  # the writer's chunks count from here (resume: a chunk end)

    def on_chunk(frames: int) -> Callable[[], None] | None:
        if backfill is not None:
            taken = snapshots.pop(frames, None)
            for stale in [n for n in snapshots if n < frames]:
                del snapshots[stale]
            if finishing[0] or taken is None:
                return None
            taken.decision_counts = state.decision_counts.copy()
            snapshot, path = taken, checkpoint_path(out_dir, frames)
        elif finishing[0] or frames - last_checkpoint[0] < every:
            return None
        else:
            last_checkpoint[0] = frames
            snapshot, path = state.snapshot(into=spare[0]), checkpoint_path(out_dir, frames)
            spare[0] = snapshot

        def commit() -> None:
            snapshot.save(path)
            committed = checkpoint_path(out_dir, writer.manifest["frame_count"])
            _remove_checkpoints(out_dir, keep={path, committed})
        return commit

    writer.on_chunk = on_chunk
    if state.window is None:
        state.allocate((int(writer.manifest["rows"]), int(writer.manifest["cols"])))
    t0 = time.perf_counter()
    main_cpu0, writer_cpu0 = time.thread_time(), writer.thread_cpu_s
    process_cpu0 = time.process_time()
    decode_cpu = [0.0]
    new_frames = 0
    # scans are read, decoded and turned into sensor grids in a thread (the second core)
    # while this one fuses
    # the fusion thread computes a scan's sensor grid itself when it would otherwise wait
    hungry = threading.Event()
    scans = prefetched(pipeline.inputs(state.scan_index, defer=hungry), depth=2,
                       name="evperc-decode", cpu_s=decode_cpu, hungry=hungry)
    bar = progress_bar(scans, total=pipeline.expected_frames(), desc=request.log_path.name,
                       initial=state.frames, enabled=progress)
    clock = pipeline.clock
    # the held frames: held by the writer (RunWriter.hold: their decision and betP(M)
    # copied out, their other layers deflated at once) where it can, else — chunks
    # deflated whole, or on_frame wanting every layer — buffers of their own, copied into
    # the writer's slot when released
    held_in_writer = backfill is not None and writer.can_hold and on_frame is None
    free_outputs: list[StoredOutputs] = []

    def hand_over(frame: dict[str, Any], out: StoredOutputs | None,
                  held: HeldLayers | None = None) -> None:
        """A finished frame to the point labels, ``on_frame`` and the writer."""
        labelled = frame.pop("point_labels", None)
        if labelled is not None:  # before the manifest counts the frame (resume redoes it)
            write_labels(out_dir, *labelled)
            clock.lap("point_labels")
        if on_frame is not None:
            on_frame({**frame, **frame_arrays(out)})
            clock.lap("on_frame")
        writer.commit_frame(**frame, held=held)
        clock.lap("write")

    def release(held: list[HeldFrame]) -> None:
        """Frames leaving the backfill: finished and committed, in order."""
        for h in held:
            frame, layers = h.payload
            frame["objects"], frame["object_cells"] = h.objects, h.object_cells
            if held_in_writer:
                pipeline.finish_frame(state, frame, layers.decision)
                hand_over(frame, None, layers)
                continue
            slot = writer.frame_slot()
            layers.copy_to(slot)
            free_outputs.append(layers)
            clock.lap("write")
            pipeline.finish_frame(state, frame, slot.decision)
            hand_over(frame, slot)

    clock.restart()
    try:
        for index, inputs in bar:
            if backfill is None or held_in_writer:
                out = writer.frame_slot()
            else:
                out = (free_outputs.pop() if free_outputs
                       else StoredOutputs.empty(tuple(state.pg.shape[1:])))
            frame = pipeline.step(state, inputs, out)
            state.scan_index = index
            new_frames += 1
            if backfill is None:
                hand_over(frame, out)
                continue
            if ((state.frames - first_frame) % writer.chunk_frames == 0
                    and state.frames - last_checkpoint[0] >= every):
                last_checkpoint[0] = state.frames  # this frame ends a chunk that checkpoints
                snapshots[state.frames] = state.snapshot()
                clock.lap("write")  # the checkpoint's copy (the causal run's is in the write)
            objects = frame["objects"]
            if held_in_writer:
                layers = writer.hold()
                decision, betp_moving = layers.decision, layers.betp_moving
                clock.lap("write")  # the writer's: the copies and the hand-over to its thread
            else:
                layers, decision, betp_moving = out, out.decision, out.betp[4]
            released = backfill.push(HeldFrame(
                frame["window"], decision, betp_moving, objects, frame["object_cells"],
                candidates(state.tracks, objects), payload=(frame, layers),
                stamp_ns=frame["stamp_ns"], occupied=frame.pop("occupied_now"),
                speaks=frame.pop("speaks"), returns=frame.pop("returns", None)))
            clock.lap("objects")
            release(released)
        if backfill is not None:  # the log's end: the frames still held
            release(backfill.flush())
    except BaseException:
        writer.abort()
        discard_if_empty()
        raise
    finally:
        bar.close()
        scans.close()  # stops and joins the decode thread
    if state.frames == 0:
        writer.abort()
        discard_if_empty()
        raise nothing_fused(request, pipeline.reader.stats)
    finishing[0] = True
    try:
        writer.finish()
    except BaseException:
        writer.abort()
        discard_if_empty()
        raise
    clock.lap("write")
    wall = time.perf_counter() - t0
    cpu_s = {"main": time.thread_time() - main_cpu0, "decode": decode_cpu[0],
             "writer": writer.thread_cpu_s - writer_cpu0}
    # the fused step's other threads (fusion.threads > 1), and any other thread
    cpu_s["other"] = max(0.0, time.process_time() - process_cpu0 - sum(cpu_s.values()))
    counts = state.decision_counts
    total = max(int(counts.sum()), 1)
    names = sorted(DECISION_CODES, key=DECISION_CODES.get)
    summary = {"frames": state.frames, "wall_time_s": round(wall, 3),
               # opening the inputs, the map, the kernels and the first scan's one-off costs
               "start_up_s": round(t0 - started, 3),
               "frames_per_s": round(new_frames / wall, 2) if wall > 0 else None,
               "decision_share": {n: round(float(counts[DECISION_CODES[n]]) / total, 6)
                                  for n in names},
               "skipped_scans": dict(pipeline.reader.stats),
               "resumed": resume,
               "sensor_grids_in_fusion_thread": pipeline.sensor_grids_in_step,
               "fusion_threads": pipeline.fusion_threads,
               "stage_ms_per_frame": dict(clock.per_frame_ms(new_frames), writer_thread=round(
                   1e3 * writer.thread_seconds / max(new_frames, 1), 3)),
               # the main thread's stages in CPU time (what each costs, without the waits)
               "stage_cpu_ms_per_frame": clock.per_frame_ms(new_frames, cpu=True),
               # CPU time of each thread over the frame loop (wall times above include the
               # time a thread waited for a core)
               "cpu_ms_per_frame": {name: round(1e3 * seconds / max(new_frames, 1), 3)
                                    for name, seconds in cpu_s.items()}}
    # the frame the log's poses are in (the child of T_crs_world): known once scans are posed
    writer.manifest["world_frame"] = pipeline.reader.posed_in
    writer.close(summary)
    _remove_checkpoints(out_dir, keep=set())
    return summary


def nothing_fused(request: RunRequest, stats: dict[str, int]) -> PoseError:
    """The error of a run that finds no scan to fuse, with the reasons scans were skipped."""
    reasons = ", ".join(f"{k} {v}" for k, v in sorted(stats.items()))
    return PoseError(f"{request.log_path}: no scan could be fused"
                     + (f" (skipped scans: {reasons})" if reasons else
                        " (no scan in the requested span)"))


def _remove_checkpoints(out_dir: Path, keep: set[Path]) -> None:
    for path in out_dir.glob(CHECKPOINT_GLOB):
        if path not in keep:
            path.unlink(missing_ok=True)


def request_from_manifest(out_dir: Path) -> RunRequest:
    """The request of an interrupted run, from its manifest (``evperc run --resume``)."""
    manifest = read_manifest(out_dir)
    if manifest.get("complete"):
        raise OutputError(f"{out_dir}: run is already complete; nothing to resume")
    saved = manifest.get("request")
    if saved is None:
        raise OutputError(f"{out_dir}: manifest has no request to resume from")
    paths = {k: (Path(v) if v is not None else None)
             for k, v in saved.items() if k in ("log_path", "map_path", "roads_path",
                                                  "config_path")}
    rest = {k: v for k, v in saved.items() if k not in paths and k != "out_dir"}
    return RunRequest(out_dir=out_dir, config=manifest["config"], **paths, **rest)
