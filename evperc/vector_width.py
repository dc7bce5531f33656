"""16-float vectors on Intel CPUs with AVX-512 (docs/performance.md § "AVX-512 on Intel").

evperc's compiled passes are written so that LLVM vectorises them across cells (the fused
step runs blocks of 256 cells as straight-line float32 code: 16 cells per AVX-512
instruction). LLVM's tuning models of Intel's AVX-512 CPUs — skylake-avx512, cascadelake,
cooperlake, icelake-client and -server, tigerlake, rocketlake, sapphirerapids,
graniterapids — carry the tuning flag
``prefer-256-bit`` (the clock penalty of 512-bit instructions on the first of them), so numba
emits 8-float vectors there, as for an AVX2 CPU, while AMD's Zen 4 and Zen 5 get 16. On a
Rocket Lake host the fused step took 15 % less time with 16-float vectors and the whole run
gained (docs/performance.md).

:func:`prefer_wide_vectors` asks numba for them: before numba is imported, it sets
``NUMBA_CPU_FEATURES`` to the host's own features (what numba would use) plus
``-prefer-256-bit``. It runs when :mod:`evperc` is imported, before any module of it imports
numba. The results do not change: the arithmetic is the same IEEE-754 operations in the
same order at any vector width (:data:`evperc.fusion.codegen.FASTMATH`), which ``make test``
checks by running the kernel and golden tests compiled for SSE2 and AVX2 CPUs too.

Left alone: a ``NUMBA_CPU_NAME`` or ``NUMBA_CPU_FEATURES`` already set (even empty: the user's
or ``make test``'s choice), ``EVPERC_WIDE_VECTORS=0``, numba already imported (its
configuration is read once), a CPU without AVX-512 (arm64, AVX2-only x86), or a host whose
features cannot be read.
"""

from __future__ import annotations

import logging
import os
import platform
import sys
from collections.abc import Callable, MutableMapping
from pathlib import Path

log = logging.getLogger(__name__)

#: set to "0" to leave numba's vector width to LLVM's model of the CPU
OPT_OUT = "EVPERC_WIDE_VECTORS"
#: LLVM's tuning flag that makes it emit 256-bit vectors on a CPU with 512-bit ones
PREFER_256 = "prefer-256-bit"
#: the ``NUMBA_CPU_FEATURES`` this process set in ``os.environ`` (None: it set none)
applied: str | None = None


def _cpuinfo_has_avx512() -> bool | None:
    """Whether the first CPU of /proc/cpuinfo lists ``avx512f``; None where there is no
    /proc/cpuinfo (or no flags line)."""
    try:
        with Path("/proc/cpuinfo").open(errors="replace") as cpuinfo:
            for line in cpuinfo:
                if line.startswith("flags"):
                    return "avx512f" in line.split()
    except OSError:
        pass
    return None


def host_features() -> str:
    """The host CPU's features as LLVM names them (``+avx2,+avx512f,...``), what numba uses
    when ``NUMBA_CPU_FEATURES`` is unset."""
    import llvmlite.binding as llvm

    llvm.initialize_native_target()
    return llvm.get_host_cpu_features().flatten()


def prefer_wide_vectors(environ: MutableMapping[str, str] | None = None,
                        features: Callable[[], str] = host_features,
                        numba_imported: bool | None = None,
                        machine: str | None = None,
                        cpuinfo_avx512: Callable[[], bool | None] = _cpuinfo_has_avx512
                        ) -> str | None:
    """Set ``NUMBA_CPU_FEATURES`` in ``environ`` (default ``os.environ``) to the host's
    features with ``-prefer-256-bit`` on an x86-64 CPU with AVX-512, unless one of the cases
    of the module docstring leaves it alone; returns the value set, or None. ``features``,
    ``numba_imported``, ``machine`` and ``cpuinfo_avx512`` (whether /proc/cpuinfo lists
    avx512f, None without it) are the host's unless given (tests)."""
    environ = os.environ if environ is None else environ
    if numba_imported is None:
        numba_imported = "numba" in sys.modules
    machine = (platform.machine() if machine is None else machine).lower()
    if (environ.get(OPT_OUT, "1") == "0" or "NUMBA_CPU_NAME" in environ
            or "NUMBA_CPU_FEATURES" in environ or numba_imported
            or machine not in ("x86_64", "amd64")):
        return None
    if cpuinfo_avx512() is False:
        return None  # the common case, answered without loading LLVM
    try:
        host = features()
    except Exception as exc:  # noqa: BLE001 - any failure leaves numba's own choice
        log.debug("host CPU features not read (%s): numba keeps LLVM's vector width", exc)
        return None
    names = host.split(",")
    if "+avx512f" not in names or f"-{PREFER_256}" in names:
        return None
    value = ",".join([n for n in names if n and n != f"+{PREFER_256}"] + [f"-{PREFER_256}"])
    environ["NUMBA_CPU_FEATURES"] = value
    if environ is os.environ:
        global applied
        applied = value
    return value


def environ_as_given() -> dict[str, str]:
    """``os.environ`` without the ``NUMBA_CPU_FEATURES`` :func:`prefer_wide_vectors` added:
    the environment for a child process that must choose for itself (a benchmark running an
    older source tree)."""
    env = dict(os.environ)
    if applied is not None and env.get("NUMBA_CPU_FEATURES") == applied:
        del env["NUMBA_CPU_FEATURES"]
    return env
