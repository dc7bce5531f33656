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

test: $(STAMP)
	$(BIN)/python -m pytest -q

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
