"""A new install's first `evperc run`: the sample drive with its map and an empty numba cache,
the kernels compiled in one process against several (evperc.warm; docs/performance.md §
"Compiling in several processes").

    python benchmarks/first_run.py [--rounds R] [--processes N] [--tree DIR]

Each round runs ``python -m evperc -q run sample_data/drive.mcap --map …`` twice, each time
with a new empty ``NUMBA_CACHE_DIR``: ``EVPERC_COMPILE_PROCESSES=1`` and ``=N`` (default:
what evperc picks, the CPUs this process may use, at most 4), in alternating order; the code
is ``--tree`` (default this repository, ``PYTHONPATH``). Prints each run's wall time, then the
medians and the median of the per-round ratios. Not part of `make bench` (a few minutes).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def first_run(tree: Path, processes: int | None) -> float:
    """Wall seconds of one run of the sample drive with an empty numba cache."""
    with tempfile.TemporaryDirectory(prefix="evperc-first-run-") as tmp:
        env = {**os.environ, "NUMBA_CACHE_DIR": str(Path(tmp) / "numba"),
               "PYTHONPATH": str(tree)}
        env.pop("EVPERC_COMPILE_PROCESSES", None)
        if processes is not None:
            env["EVPERC_COMPILE_PROCESSES"] = str(processes)
        sample = ROOT / "sample_data"
        start = time.perf_counter()
        subprocess.run([sys.executable, "-m", "evperc", "-q", "run", str(sample / "drive.mcap"),
                        "--map", str(sample / "map.geojson"), "--out", str(Path(tmp) / "out")],
                       env=env, cwd=tree, check=True, stdout=subprocess.DEVNULL)
        return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--processes", type=int, default=None,
                        help="the several-process case (default: evperc's own choice)")
    parser.add_argument("--tree", type=Path, default=ROOT)
    args = parser.parse_args()
    label = f"{args.processes} processes" if args.processes else "evperc's choice"
    cases = [("1 process", 1), (label, args.processes)]
    times: dict[str, list[float]] = {name: [] for name, _ in cases}
    for round_ in range(args.rounds):
        for name, processes in (cases if round_ % 2 == 0 else cases[::-1]):
            seconds = first_run(args.tree.resolve(), processes)
            times[name].append(seconds)
            print(f"round {round_ + 1}: {name}: {seconds:.1f} s", flush=True)
    for name, values in times.items():
        print(f"{name}: median {statistics.median(values):.1f} s "
              f"({min(values):.1f}-{max(values):.1f})")
    ratios = [b / a for a, b in zip(times[cases[0][0]], times[cases[1][0]], strict=True)]
    print(f"{cases[1][0]} / 1 process: median {statistics.median(ratios):.2f} "
          f"({min(ratios):.2f}-{max(ratios):.2f}, {len(ratios)} rounds)")


if __name__ == "__main__":
    main()
