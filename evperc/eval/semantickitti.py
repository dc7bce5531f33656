"""Scoring per-point labels against SemanticKITTI, as the LiDAR-MOS benchmark does.

``evperc evaluate RUN --semantickitti SEQ_DIR`` reads the run's ``RUN/labels/NNNNNN.label``
(written by ``evperc run --point-labels``) and the sequence's ``SEQ_DIR/labels/NNNNNN.label``,
matched by file name. Truth classes are the low 16 bits of the SemanticKITTI label:

- 0 *unlabeled* and 1 *outlier* are ignored (left out of every count);
- 252–259 (moving-car … moving-other-vehicle) are *moving*;
- every other class is *static* (parked cars included).

A prediction is *moving* when its low 16 bits are 251 or 252–259, anything else (9, 0) is not
moving. Over the labelled points, with TP / FP / FN / TN the moving-class confusion counts:

- IoU of moving = TP / (TP + FP + FN) (the benchmark's figure, Chen et al. 2021),
- precision = TP / (TP + FP), recall = TP / (TP + FN),
- static → moving = FP / (FP + TN), the share of static points decided moving.

A ratio with a zero denominator is ``None`` (e.g. recall on a scan with nothing moving).
Scores are given per scan and pooled (counts summed, then the ratios) over the scans after
the first ``warmup`` of the run, which are pooled apart: the evidential grid has no history
in its first scans, so nothing can be decided moving there yet.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from evperc.errors import LogError, OutputError

#: SemanticKITTI classes left out of the scores
IGNORED_CLASSES = (0, 1)
#: SemanticKITTI moving classes (moving-car … moving-other-vehicle)
MOVING_CLASSES = tuple(range(252, 260))
#: the MOS prediction label of moving points
MOVING_LABEL = 251
COUNTS = ("tp", "fp", "fn", "tn")


def read_label_file(path: Path) -> np.ndarray:
    """The uint32 labels of one ``.label`` file (little-endian)."""
    try:
        data = path.read_bytes()
    except OSError as err:
        raise LogError(f"{path}: cannot read labels ({err.strerror})") from err
    if len(data) % 4:
        raise LogError(f"{path}: truncated label file ({len(data)} bytes, not a multiple of 4)")
    return np.frombuffer(data, "<u4")


def point_masks(pred: np.ndarray, truth: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per point of one scan (bool): ``said`` moving by the run (the moving label or a
    moving class), ``labelled`` (not an ignored class) and truly ``moving`` (module doc);
    instance ids (the upper 16 bits) are dropped."""
    cls = truth & 0xFFFF
    p = pred & 0xFFFF
    return ((p == MOVING_LABEL) | np.isin(p, MOVING_CLASSES), ~np.isin(cls, IGNORED_CLASSES),
            np.isin(cls, MOVING_CLASSES))


def confusion(pred: np.ndarray, truth: np.ndarray) -> dict[str, int]:
    """Moving-class counts ``tp, fp, fn, tn`` and ``ignored`` of one scan (module doc)."""
    said, labelled, moving = point_masks(pred, truth)
    tp = int((said & moving).sum())
    fp = int((said & labelled & ~moving).sum())
    fn = int((~said & moving).sum())
    tn = int((~said & labelled & ~moving).sum())
    return {"tp": tp, "fp": fp, "fn": fn, "tn": tn, "ignored": int((~labelled).sum())}


def _ratio(num: int, den: int) -> float | None:
    return num / den if den else None


def scores(counts: dict[str, int]) -> dict[str, Any]:
    """``counts`` with IoU, precision, recall and the static → moving share."""
    tp, fp, fn, tn = (counts[k] for k in COUNTS)
    return {**counts, "iou": _ratio(tp, tp + fp + fn), "precision": _ratio(tp, tp + fp),
            "recall": _ratio(tp, tp + fn), "static_as_moving": _ratio(fp, fp + tn),
            "moving_truth": tp + fn}


def _pooled(rows: list[dict[str, Any]]) -> dict[str, Any]:
    counts = {k: sum(r[k] for r in rows) for k in (*COUNTS, "ignored")}
    return {"scans": len(rows), **scores(counts)}


def evaluate_semantickitti(run_dir: str | Path, seq_dir: str | Path,
                           warmup: int = 2) -> dict[str, Any]:
    """Per-scan and pooled scores of ``run_dir``'s point labels against ``seq_dir``'s.

    Returns ``{"per_scan": [...], "overall": {...}, "warmup": {...}, "warmup_scans": K,
    "not_predicted": [...]}``; ``overall`` pools the scans after the first ``warmup`` of the
    run, ``warmup`` the first ones. ``not_predicted`` lists truth files the run has no labels
    for (scans outside the run's span). Raises :class:`OutputError` when the run has no
    labels, :class:`LogError` when the sequence has none, or a file pair differs in length.
    """
    run_labels = Path(run_dir) / "labels"
    truth_labels = Path(seq_dir) / "labels"
    predicted = sorted(run_labels.glob("*.label")) if run_labels.is_dir() else []
    if not predicted:
        raise OutputError(f"{run_dir}: no point labels (labels/*.label); run `evperc run` "
                          "with --point-labels")
    truth = {p.name: p for p in truth_labels.glob("*.label")} if truth_labels.is_dir() else {}
    if not truth:
        raise LogError(f"{seq_dir}: no SemanticKITTI labels (labels/*.label); give the "
                       "sequence folder that holds velodyne/ and labels/")
    rows = []
    for path in predicted:
        if path.name not in truth:
            raise LogError(f"{truth_labels / path.name}: no truth for the run's scan "
                           f"{path.stem}; is {seq_dir} the sequence of the run?")
        pred, gt = read_label_file(path), read_label_file(truth[path.name])
        if len(pred) != len(gt):
            raise LogError(f"{path}: {len(pred)} labels, {truth[path.name]} has {len(gt)}; "
                           "not the same scan")
        rows.append({"scan": path.stem, "points": len(gt), **scores(confusion(pred, gt))})
    names = {p.name for p in predicted}
    warmup = max(0, int(warmup))
    return {"per_scan": rows, "warmup_scans": min(warmup, len(rows)),
            "warmup": _pooled(rows[:warmup]), "overall": _pooled(rows[warmup:]),
            "not_predicted": sorted(Path(n).stem for n in truth if n not in names),
            "cell_scores": None,
            "cell_scores_note": "SemanticKITTI labels points, not cells: there is no truth of "
                                "free, infrastructure or stopped cells to score the grid with"}


def _fmt(value: float | None, percent: bool = False) -> str:
    if value is None:
        return "-"
    return f"{100 * value:.2f}%" if percent else f"{value:.3f}"


def format_semantickitti(result: dict[str, Any]) -> str:
    """Plain-text table: one line a scan, then the warm-up and the pooled rows."""
    lines = [f"{'scan':<10} {'moving':>7} {'TP':>6} {'FP':>6} {'FN':>6} {'IoU':>6} "
             f"{'P':>6} {'R':>6} {'static->moving':>14}"]

    def line(name: str, r: dict[str, Any]) -> str:
        return (f"{name:<10} {r['moving_truth']:>7} {r['tp']:>6} {r['fp']:>6} {r['fn']:>6} "
                f"{_fmt(r['iou']):>6} {_fmt(r['precision']):>6} {_fmt(r['recall']):>6} "
                f"{_fmt(r['static_as_moving'], True):>14}")

    k = result["warmup_scans"]
    for i, r in enumerate(result["per_scan"]):
        lines.append(line(r["scan"] + (" (w)" if i < k else ""), r))
    if k:
        lines.append(line(f"warm-up {k}", result["warmup"]))
    lines.append(line(f"all {result['overall']['scans']}", result["overall"]))
    if result["not_predicted"]:
        lines.append(f"{len(result['not_predicted'])} labelled scans not in the run")
    return "\n".join(lines) + "\n"
