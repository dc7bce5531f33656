# evperc — make targets. Every target creates .venv if it is missing.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= evperc-out

.PHONY: run test test-all bench lint golden sample-data clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(BIN)/evperc run sample_data/drive.mcap --map sample_data/map.geojson --out $(OUT)/sample --overwrite
	$(BIN)/evperc render $(OUT)/sample --gif $(OUT)/sample.gif --out $(OUT)/sample-png --overwrite

# The bundled drive: 20 s, ibeo4 profile, seed 7, on the Helsinki OSM extract (tests/data/osm).
sample-data: $(STAMP)
	rm -rf sample_data.tmp
	$(BIN)/evperc simulate --map tests/data/osm/helsinki_buildings.geojson \
		--roads tests/data/osm/helsinki_roads.geojson --profile ibeo4 --seconds 20 --seed 7 \
		--out sample_data.tmp
	rm -rf sample_data/truth
	mv sample_data.tmp/drive.mcap sample_data.tmp/map.geojson sample_data.tmp/truth sample_data/
	rm -rf sample_data.tmp

# `make test` runs the fused-kernel and golden tests a second time for each CPU model below,
# with numba compiling for that CPU instead of the host's (NUMBA_CPU_NAME, and
# NUMBA_CPU_FEATURES empty: the model's own features, not the host's), each with its own
# numba cache: x86-64 is SSE2 (4 floats a vector), haswell AVX2 + FMA (8). So a machine
# with AVX-512 also tests the code LLVM writes for plainer CPUs (issue 17: bits that
# depended on the vector width). x86 models only on x86-64 hosts (arm64: none); haswell
# only on hosts with AVX-512 (on an AVX2 host the main suite already runs 8-float code).
# The passes run beside the main suite (each compiles its kernels, ~2-3 min of CPU), at a
# lower priority (nice): the main suite, one process, is the longest path, and the passes
# take what CPU it leaves, so that on 2 cores the whole stays within 10 minutes (7 m 11 s
# with the install on a 2-vCPU Xeon, the main suite's first run compiling in two processes:
# docs/performance.md § "Compiling in several processes").
HOST_AVX512 := $(shell grep -qw avx512f /proc/cpuinfo 2>/dev/null && echo yes)
PLAIN_CPUS ?= $(if $(filter x86_64 amd64,$(shell uname -m)),x86-64 $(if $(HOST_AVX512),haswell,),)
# the tests that compare code paths bit for bit (where the vector width showed), and the goldens
PLAIN_CPU_TESTS := tests/fusion/test_fused.py tests/golden -k \
	'skip_path or circular_buffer or lane or lean_kernel_equals or threads_write or golden'
NUMBA_CACHE_ROOT ?= $(VENV)/numba-cache

test: $(STAMP)
	@mkdir -p $(NUMBA_CACHE_ROOT); pids=; for cpu in $(PLAIN_CPUS); do \
		echo "numba compiling for CPU $$cpu: $(PLAIN_CPU_TESTS) (log: $(NUMBA_CACHE_ROOT)/$$cpu.log)"; \
		NUMBA_CPU_NAME=$$cpu NUMBA_CPU_FEATURES= NUMBA_CACHE_DIR=$(NUMBA_CACHE_ROOT)/$$cpu \
			nice -n 10 $(BIN)/python -m pytest -q -p no:cacheprovider $(PLAIN_CPU_TESTS) \
			>$(NUMBA_CACHE_ROOT)/$$cpu.log 2>&1 & pids="$$pids $$!"; \
	done; status=0; $(BIN)/python -m pytest -q || status=1; \
	for pid in $$pids; do wait $$pid || status=1; done; \
	for cpu in $(PLAIN_CPUS); do echo "== CPU $$cpu"; tail -n 15 $(NUMBA_CACHE_ROOT)/$$cpu.log; done; \
	exit $$status

test-all: $(STAMP)
	$(BIN)/python -m pytest -q -m ''

bench: $(STAMP)
	$(BIN)/python benchmarks/run.py

# Rewrite tests/golden/ after an intended change of results; review the diff, then commit.
golden: $(STAMP)
	$(BIN)/python -m tests.golden.update

lint: $(STAMP)
	$(BIN)/ruff check evperc tests benchmarks

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache
