"""evperc: map-aided evidential occupancy grids from logged drives.

Implements Kurdej, Moras, Cherfaoui, Bonnifait, "Enhancing Mobile Object Classification Using
Geo-referenced Maps and Evidential Grids" (2013), as specified in docs/method.md.
"""

from __future__ import annotations

from evperc.vector_width import prefer_wide_vectors

# before any module of evperc imports numba: 16-float vectors on Intel's AVX-512 CPUs too
prefer_wide_vectors()

__version__ = "0.1.0"

__all__ = ["__version__", "load"]


def load(out_dir):  # noqa: ANN001, ANN201 - thin re-export, documented in evperc.output.reader
    """Open an `evperc run` output directory; see :func:`evperc.output.reader.load`."""
    from evperc.output.reader import load as _load

    return _load(out_dir)
