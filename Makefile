# Two commands do everything on a fresh machine:  make demo  |  make test
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.neoedit-installed
DEMO_OUT ?= outputs/demo

.PHONY: setup demo test lint bench-sim clean

setup: $(STAMP)

# Torch first, pinned to the local CPU build when torch is missing (a looser requirement
# would pull several GB of CUDA packages); then the package with its dev tools.
$(STAMP): pyproject.toml
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -c "import torch" 2>/dev/null || $(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e ".[dev]"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/neo sim benchmark --profile small --only removal_1 pick_place_1 --out $(DEMO_OUT)/sim
	@echo "contact sheets:"; ls $(DEMO_OUT)/sim/*/*/contact_sheet.png

test: $(STAMP)
	$(PY) -m pytest tests

lint: $(STAMP)
	$(VENV)/bin/ruff check neoedit tests benchmarks
	$(VENV)/bin/ruff format --check neoedit tests benchmarks
	$(VENV)/bin/mypy

bench-sim: $(STAMP)
	$(PY) benchmarks/bench_sim.py --profile standard --out outputs/neosim_standard

clean:
	rm -rf $(VENV) outputs build *.egg-info
