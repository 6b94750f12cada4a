# Two entry points, each self-contained on a fresh Debian-like machine:
#   make quickstart   install everything, then run the main job
#   make test         install everything, then run the test suite
PYTHON ?= python3
SUDO := $(shell [ "$$(id -u)" = "0" ] || echo sudo)
WORKERS ?= 2

.PHONY: install system-deps quickstart test test-all bench

system-deps:
	@# open3d needs libusb-1.0 to import.
	@if command -v apt-get >/dev/null && ! ldconfig -p | grep -q libusb-1.0; then \
		$(SUDO) apt-get update -qq && $(SUDO) apt-get install -y -qq libusb-1.0-0; fi

install: system-deps
	@# torch first and exactly: the local CPU build; a newer torch would pull GBs of CUDA wheels.
	$(PYTHON) -m pip install -q torch==2.13.0
	$(PYTHON) -m pip install -q -e ".[dev,ray]"

quickstart: install
	@# Re-runnable: a finished store is kept, an interrupted one is resumed.
	@if physdyn data info data/quickstart.zarr >/dev/null 2>&1; then echo "data/quickstart.zarr exists; kept"; \
	else physdyn simulate --config configs/data/quickstart.yaml --out data/quickstart.zarr --workers $(WORKERS) \
		$$([ -d data/quickstart.zarr ] && echo --resume); fi
	physdyn data info data/quickstart.zarr

test: install
	$(PYTHON) -m pytest

test-all: install
	$(PYTHON) -m pytest -m "slow or not slow"

bench: install
	$(PYTHON) benchmarks/simulate.py
