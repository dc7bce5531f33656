"""The object list of a frame as the output format stores it (docs/output-format.md,
"Objects"): one record per reported object, and the window cells of each object.

Defined here, with the output format, so that the writer and the reader need nothing of the
object stages (:mod:`evperc.objects`), which produce these records."""

from __future__ import annotations

import numpy as np

#: ``state`` codes of an object record
OBJECT_STATES = {"moving": 1, "stopped": 2}

#: one reported object (fields in the working CRS: x east, y north, metres, m/s)
OBJECT_DTYPE = np.dtype([
    ("track_id", np.uint32),            # stable over the frames of a track, from 1
    ("state", np.uint8),                # OBJECT_STATES
    ("cell_count", np.uint32),          # cells of the object in this frame
    ("age_frames", np.uint32),          # frames the track has been associated with a cluster
    ("centroid_m", np.float64, (2,)),   # mean of the cell centres, x, y
    ("bbox_m", np.float64, (4,)),       # xmin, ymin, xmax, ymax of the cells' outer edges
    ("extent_m", np.float32, (2,)),     # bbox size along x and y
    ("velocity_m_per_s", np.float32, (2,)),  # constant-velocity fit, x east, y north
    ("speed_sigma_m_per_s", np.float32),     # standard deviation of each velocity component
    ("mean_betp_moving", np.float32),   # mean betP(M) over the object's cells
])


def empty_objects() -> np.ndarray:
    """A frame without objects."""
    return np.zeros(0, OBJECT_DTYPE)


def object_labels(objects: np.ndarray, cells: np.ndarray, shape: tuple[int, int]
                  ) -> np.ndarray:
    """``(rows, cols)`` uint32: each object's cells set to its track id, 0 elsewhere.

    ``cells``: the flat window indices (``row · cols + col``) of the objects, concatenated
    in record order, ``objects["cell_count"]`` of them each."""
    labels = np.zeros(shape[0] * shape[1], np.uint32)
    counts = objects["cell_count"].astype(np.int64)
    if counts.sum() != cells.size:
        raise ValueError(f"{cells.size} object cells, the records list {int(counts.sum())}")
    labels[cells.astype(np.int64)] = np.repeat(objects["track_id"], counts)
    return labels.reshape(shape)


def moving_object_cells(objects: np.ndarray | None, cells: np.ndarray | None
                        ) -> np.ndarray | None:
    """The flat window cells of the frame's moving objects (records of
    :data:`evperc.output.objects.OBJECT_DTYPE` and their cells, as the object stage returns
    them), None without an object list."""
    if objects is None or cells is None:
        return None
    counts = objects["cell_count"].astype(np.int64)
    moving = np.repeat(objects["state"] == OBJECT_STATES["moving"], counts)
    return np.asarray(cells, np.int64)[moving]


def record_cells(objects: np.ndarray, cells: np.ndarray) -> list[np.ndarray]:
    """Each record's flat window cells (int64), in record order: ``cells`` holds them
    concatenated, ``objects["cell_count"]`` each (as the object stage and the chunks do)."""
    counts = objects["cell_count"].astype(np.int64)
    flat = np.asarray(cells, np.int64)
    if counts.sum() != flat.size:
        raise ValueError(f"{flat.size} object cells, the records list {int(counts.sum())}")
    return np.split(flat, np.cumsum(counts)[:-1]) if len(counts) else []
