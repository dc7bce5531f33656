"""evperc.vector_width: numba asked for 16-float vectors on x86-64 CPUs with AVX-512, and left
alone in every other case. That the results do not depend on the vector width is tested by
``make test``'s second run of the kernel and golden tests compiled for SSE2 and AVX2 CPUs."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from evperc import vector_width
from evperc.vector_width import environ_as_given, prefer_wide_vectors

AVX512_HOST = "+avx2,+avx512f,+avx512bw,+prefer-256-bit,+sse4.2"


def never() -> str:
    raise AssertionError("the host's features were read although the case needs none")


def apply(environ: dict[str, str], features=lambda: AVX512_HOST, **kw) -> str | None:
    kw = {"numba_imported": False, "machine": "x86_64", "cpuinfo_avx512": lambda: True, **kw}
    return prefer_wide_vectors(environ, features=features, **kw)


def test_avx512_host_gets_the_host_features_without_the_256_bit_preference():
    environ: dict[str, str] = {}
    value = apply(environ)
    assert environ == {"NUMBA_CPU_FEATURES": value}
    names = value.split(",")
    # every feature of the host kept, in its order; LLVM's preference turned off, last
    assert names == ["+avx2", "+avx512f", "+avx512bw", "+sse4.2", "-prefer-256-bit"]


def test_windows_and_macos_names_of_x86_64_and_no_cpuinfo():
    for machine in ("AMD64", "x86_64"):
        environ: dict[str, str] = {}
        assert apply(environ, machine=machine, cpuinfo_avx512=lambda: None) is not None
        assert environ["NUMBA_CPU_FEATURES"].endswith(",-prefer-256-bit")


@pytest.mark.parametrize("environ", [
    {"NUMBA_CPU_FEATURES": ""},            # make test's plain-CPU runs: the model's features
    {"NUMBA_CPU_FEATURES": "+avx2"},       # the user's choice
    {"NUMBA_CPU_NAME": "haswell"},         # a CPU model asked for
    {"EVPERC_WIDE_VECTORS": "0"},          # the opt-out
])
def test_an_explicit_choice_is_left_alone(environ):
    before = dict(environ)
    assert apply(environ, features=never) is None
    assert environ == before


@pytest.mark.parametrize("kw", [
    {"numba_imported": True},                          # its configuration already read
    {"machine": "arm64"}, {"machine": "aarch64"},      # an arm64 Mac, a Graviton
    {"cpuinfo_avx512": lambda: False},                 # an AVX2 laptop: LLVM not loaded
])
def test_other_hosts_are_left_alone_without_reading_the_features(kw):
    environ: dict[str, str] = {}
    assert apply(environ, features=never, **kw) is None
    assert environ == {}


def failing() -> str:
    raise OSError("no LLVM here")


@pytest.mark.parametrize("features", [
    lambda: "+avx2,+fma,+sse4.2",                    # no AVX-512 (cpuinfo unknown)
    lambda: "+avx2,+avx512f,-prefer-256-bit",        # already asked
    failing,                                         # the query failed
])
def test_hosts_without_avx512_or_an_answer_are_left_alone(features):
    environ: dict[str, str] = {}
    assert apply(environ, features=features, cpuinfo_avx512=lambda: None) is None
    assert environ == {}


def test_environ_as_given_drops_only_what_evperc_added(monkeypatch):
    monkeypatch.delenv("NUMBA_CPU_FEATURES", raising=False)
    monkeypatch.delenv("NUMBA_CPU_NAME", raising=False)
    monkeypatch.delenv("EVPERC_WIDE_VECTORS", raising=False)
    monkeypatch.setattr(vector_width, "applied", None)
    value = prefer_wide_vectors(features=lambda: AVX512_HOST, numba_imported=False,
                                machine="x86_64", cpuinfo_avx512=lambda: True)
    assert os.environ["NUMBA_CPU_FEATURES"] == value
    assert "NUMBA_CPU_FEATURES" not in environ_as_given()
    monkeypatch.setenv("NUMBA_CPU_FEATURES", "+avx2")  # changed since: the user's
    assert environ_as_given()["NUMBA_CPU_FEATURES"] == "+avx2"


HOST_AVX512 = (vector_width._cpuinfo_has_avx512() is True
               and "+avx512f" in vector_width.host_features().split(","))

PROBE = """
import evperc, os, numba, numpy as np
@numba.njit
def fma(a, b, c):
    for i in range(a.shape[0]):
        c[i] = a[i] * b[i] + c[i]
a = np.ones(1024, np.float32)
fma(a, a, a.copy())
print(os.environ.get("NUMBA_CPU_FEATURES", "").endswith(",-prefer-256-bit"),
      "zmm" in fma.inspect_asm(fma.signatures[0]))
"""


@pytest.mark.skipif(not HOST_AVX512, reason="the host has no AVX-512: nothing to ask for")
def test_importing_evperc_gives_numba_512_bit_vectors(tmp_path):
    """On this host, in a fresh interpreter: ``import evperc`` before numba, and a float32
    loop compiles to 512-bit (zmm) instructions — on an Intel host LLVM's own choice would be
    256-bit (ymm) ones."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CPU_FEATURES", "NUMBA_CPU_NAME", "EVPERC_WIDE_VECTORS")}
    env["NUMBA_CACHE_DIR"] = str(tmp_path)
    done = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True,
                          text=True, check=True)
    assert done.stdout.split() == ["True", "True"]
