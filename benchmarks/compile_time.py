"""First compile of each fused kernel, in a fresh numba cache, optionally per numba pass
(docs/performance.md § "The kernels' compile time").

    python benchmarks/compile_time.py [--tree DIR] [--passes] [KERNEL ...]

Each kernel is compiled in a process of its own with an empty ``NUMBA_CACHE_DIR`` (one
``fused_step`` call on a 24 × 300 window), ``PYTHONPATH`` = ``--tree`` (default: this
repository; e.g. a ``git worktree`` of an older commit), so that trees are compared on one
machine. KERNEL: ``step_stored_lean`` (what every default run uses), ``step_stored``,
``step_float_lean``, ``step_float``; default all four. Beside each time, the final LLVM IR's
select instructions and the calls left to ``_sel`` (evperc.fusion.single_assignment: 0, LLVM
inlined it). ``--passes``: the eight numba passes that took longest, per kernel.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KERNELS = ("step_stored_lean", "step_stored", "step_float_lean", "step_float")

CHILD = r"""
import collections, sys, time
from numba.core import compiler_machinery
totals = collections.Counter()
run_pass = compiler_machinery.PassManager._runPass
def timed(self, index, pss, state):
    start = time.perf_counter()
    try:
        return run_pass(self, index, pss, state)
    finally:
        totals[pss.name()] += time.perf_counter() - start
compiler_machinery.PassManager._runPass = timed
import numpy as np
from evperc.fusion.fused import FusedOutputs, StoredOutputs, focal_sets, fused_step, vacuous_flags
from evperc.fusion.twin import FusionParams
name = sys.argv[1]
rng = np.random.default_rng(0)
shape = (24, 300)
pg = np.zeros((32, *shape), np.float32)
pg[31] = 1
zeta = np.zeros(shape, np.float32)
free = np.where(rng.random(shape) < 0.3, 0.7, 0.0).astype(np.float32)
occupied = np.where(free == 0, 0.8, 0.0).astype(np.float32)
labels = rng.choice(np.array([0, 1, 2], np.uint8), size=shape)
# the lean kernels serve the default (contextual) discounting, the general ones the others
params = FusionParams() if name.endswith("_lean") else FusionParams(discount="classical")
out = (FusedOutputs if "float" in name else StoredOutputs).empty(shape)
start = time.perf_counter()
fused_step(pg, zeta, free, occupied, labels, (0.9, 0.9, 0.8), 0.1, params, out=out,
           flags=vacuous_flags(pg, zeta), focal=focal_sets(pg))
print(f"{time.perf_counter() - start:.1f}")
from evperc.fusion import kernel
dispatcher = getattr(kernel, name)
final_ir = dispatcher.overloads[dispatcher.signatures[0]].library.get_llvm_str()
left = sum(" call " in line and "_sel" in line for line in final_ir.splitlines())
print(f"calls_to_select {left}")
print(f"selects {final_ir.count(' select ')}")
for pass_name, seconds in totals.most_common(8):
    print(f"{pass_name} {seconds:.1f}")
"""


def compile_once(tree: Path, kernel: str) -> tuple[float, dict[str, int], list[tuple[str, float]]]:
    """Seconds of the kernel's first call with an empty cache; in the final LLVM IR, the
    calls left to ``_sel`` (0: inlined) and the select instructions; the slowest passes."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache, "PYTHONPATH": str(tree)}
        done = subprocess.run([sys.executable, "-c", CHILD, kernel], env=env, cwd=tree,
                              capture_output=True, text=True, check=True)
    first, calls, selects, *passes = done.stdout.split("\n")
    counts = {line.split()[0]: int(line.split()[1]) for line in (calls, selects)}
    return (float(first), counts,
            [(p.split()[0], float(p.split()[1])) for p in passes if p.strip()])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("kernels", nargs="*", metavar="KERNEL")
    parser.add_argument("--tree", type=Path, default=ROOT)
    parser.add_argument("--passes", action="store_true")
    args = parser.parse_args()
    unknown = sorted(set(args.kernels) - set(KERNELS))
    if unknown:
        parser.error(f"unknown kernel {unknown[0]}: one of {', '.join(KERNELS)}")
    total = 0.0
    for kernel in args.kernels or KERNELS:
        seconds, counts, passes = compile_once(args.tree.resolve(), kernel)
        total += seconds
        print(f"{kernel:18s} {seconds:6.1f} s   final IR: {counts['selects']} selects, "
              f"{counts['calls_to_select']} calls left to _sel")
        if args.passes:
            for name, spent in passes:
                print(f"    {name:32s} {spent:6.1f} s")
    print(f"{'total':18s} {total:6.1f} s")


if __name__ == "__main__":
    main()
