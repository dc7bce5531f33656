"""`make bench`: run every benchmark module of this folder and print its table.

Each ``bench_*.py`` exposes ``run() -> list[dict]``; rows are printed as aligned columns.
Select modules with arguments: ``python benchmarks/run.py dst sensor``.
"""

from __future__ import annotations

import importlib
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def print_table(title: str, rows: list[dict]) -> None:
    print(f"\n## {title}")
    if not rows:
        print("(no rows)")
        return
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row if k not in keys]
    cells = [[_fmt(row.get(k, "")) for k in keys] for row in rows]
    widths = [max(len(k), *(len(c[i]) for c in cells)) for i, k in enumerate(keys)]
    print("  ".join(k.ljust(w) for k, w in zip(keys, widths, strict=True)))
    for c in cells:
        print("  ".join(v.ljust(w) for v, w in zip(c, widths, strict=True)))


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}" if abs(value) < 1e5 else f"{value:.3e}"
    return str(value)


def cpu() -> str:
    """The CPU model, its widest float vectors, and the CPU numba compiles for (speed
    figures name both: the fused kernel runs 4, 8 or 16 cells per instruction)."""
    import llvmlite.binding as llvm
    from numba.core import config

    info = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    model = next((line.split(":", 1)[1].strip() for line in info.splitlines()
                  if line.startswith("model name")), platform.processor() or platform.machine())
    flags = set(next((line.split(":", 1)[1].split() for line in info.splitlines()
                      if line.startswith("flags")), []))
    if platform.machine() in ("arm64", "aarch64"):
        width = "NEON, 128-bit"
    else:
        width = ("AVX-512, 512-bit" if "avx512f" in flags else "AVX2, 256-bit" if "avx2" in flags
                 else "SSE2, 128-bit" if flags else "vector width unknown")
    target = config.CPU_NAME or llvm.get_host_cpu_name()
    return f"{model} ({width}), numba target {target}"


def main(argv: list[str]) -> int:
    sys.path.insert(0, str(HERE))
    names = argv or sorted(p.stem.removeprefix("bench_") for p in HERE.glob("bench_*.py"))
    print(f"# evperc benchmarks — {cpu()}, "
          f"Python {platform.python_version()}, {time.strftime('%Y-%m-%d %H:%M')}")
    for name in names:
        module = importlib.import_module(f"bench_{name}")
        t0 = time.perf_counter()
        rows = module.run()
        print_table(f"{name} ({time.perf_counter() - t0:.1f} s)", rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
