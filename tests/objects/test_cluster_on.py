"""objects.cluster_on: the clusters' occupied-now cells from all returns of a scan.

"all_returns_join" (the runner passes ``occupied_now`` as uint8 with
:data:`~evperc.objects.clusters.JOINS_ANY` at cells holding only returns behind the first
one of their azimuth bin): such a cell decided unknown joins a cluster growing next to it
as a leaf (it grows the cluster no further) and never seeds one; decided free or
infrastructure it does not join. Hand-made grids; expected cells worked out by hand."""

from __future__ import annotations

import numpy as np

from evperc.fusion.twin import DECISION_CODES as D
from evperc.geo.window import Window
from evperc.objects.clusters import JOINS_ANY, Clusterer, ClusterParams

WIN = Window(0.5, 8, 10, 0, 0)
PARAMS = ClusterParams(min_cells=3, seeds="occupied")


def _clusters(dec: np.ndarray, now: np.ndarray):
    zeros = np.zeros(dec.shape, np.uint8)
    return Clusterer(PARAMS, dec.shape).clusters(dec, zeros, zeros, WIN, None, now)


def _scene():
    """A far object: two first-return cells (static), behind them three cells with returns
    the sensor grid leaves unknown (decided unknown, unknown, free), a mapped building cell
    holding a return; a chain of hit-only unknown cells off the leaf; three hit-only cells
    decided unknown, alone."""
    dec = np.full(WIN.shape, D["free"], np.uint8)
    now = np.zeros(WIN.shape, np.uint8)
    dec[3, 2:4] = D["static"]
    now[3, 2:4] = 1                                   # first returns, sensor occupied
    dec[3, 4] = dec[4, 4] = D["unknown"]              # returns behind them
    dec[4, 2] = D["free"]
    dec[2, 4] = D["infrastructure"]
    now[3, 4] = now[4, 4] = now[4, 2] = now[2, 4] = JOINS_ANY
    dec[5, 5] = dec[6, 5] = D["unknown"]              # a chain beyond the leaf (4, 4)
    now[5, 5] = now[6, 5] = JOINS_ANY
    dec[6, 7:10] = D["unknown"]
    now[6, 7:10] = JOINS_ANY                          # hit-only cells, alone
    return dec, now


def test_hit_only_unknown_cells_join_a_growing_cluster_as_leaves():
    dec, now = _scene()
    c = _clusters(dec, now)
    # (3,2) (3,3) seed; (3,4) and (4,4) unknown join; (4,2) free and (2,4) infrastructure
    # do not; (5,5) touches only the leaf (4,4): not taken; the lone row (6, 7..9) seeds
    # nothing
    assert len(c) == 1
    assert sorted(c.cells_of(0)) == [3 * 10 + 2, 3 * 10 + 3, 3 * 10 + 4, 4 * 10 + 4]


def test_without_join_the_far_object_is_below_min_cells():
    dec, now = _scene()
    # "all_returns" (a plain OR): the hit-only cells are occupied-now cells but grow only
    # through occupied decisions -> the object is 2 cells < 3, dropped
    assert len(_clusters(dec, now > 0)) == 0
    assert len(_clusters(dec, now == 1)) == 0     # first returns only
