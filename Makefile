# Two entry points, each self-contained on a fresh Debian-like machine:
#   make quickstart   install everything, then run the main job
#   make test         install everything, then run the test suite
PYTHON ?= python3
SUDO := $(shell [ "$$(id -u)" = "0" ] || echo sudo)
WORKERS ?= 2
# The default suite on two pytest-xdist workers: 4:17 one at a time on the 2-core machine, under 3 minutes on two.
TEST_WORKERS ?= 2

.PHONY: install system-deps quickstart test test-all bench

system-deps:
	@# open3d needs libusb-1.0 to import.
	@if command -v apt-get >/dev/null && ! ldconfig -p | grep -q libusb-1.0; then \
		$(SUDO) apt-get update -qq && $(SUDO) apt-get install -y -qq libusb-1.0-0; fi

install: system-deps
	@# torch first and exactly: the local CPU build; a newer torch would pull GBs of CUDA wheels.
	$(PYTHON) -m pip install -q torch==2.13.0
	$(PYTHON) -m pip install -q -e ".[dev,ray]"
	@# The example encoder plugin, so the tests train it beside the built-ins (no deps: torch stays put).
	$(PYTHON) -m pip install -q --no-deps --no-build-isolation -e plugins/physdyn-dgcnn

quickstart: install
	@# The main job, re-runnable: finished steps are kept, interrupted ones resumed.
	@if physdyn data info data/quickstart.zarr >/dev/null 2>&1; then echo "data/quickstart.zarr exists; kept"; \
	else physdyn simulate --config configs/data/quickstart.yaml --out data/quickstart.zarr --workers $(WORKERS) \
		$$([ -d data/quickstart.zarr ] && echo --resume); fi
	physdyn data info data/quickstart.zarr
	@if [ -f runs/quickstart/finished.json ]; then echo "runs/quickstart is trained; kept"; \
	else physdyn fit --config configs/experiment/quickstart.yaml $$([ -f runs/quickstart/last.ckpt ] && echo --resume); fi
	physdyn fit-topple --checkpoint runs/quickstart/best.ckpt --out runs/quickstart/best_topple.ckpt --physics --overwrite
	@# the bundled model's hybrid: the first 0.4 s simulated from the cloud, the rest from the networks
	$(PYTHON) -m physdyn.models.export runs/quickstart/best_topple.ckpt runs/quickstart/hybrid.ckpt --set model.sim_seconds=0.4 --overwrite
	physdyn test --checkpoint runs/quickstart/hybrid.ckpt --data data/quickstart.zarr --out reports/quickstart --overwrite
	physdyn predict examples/meshes/bracket_mm.obj --scale 0.001 --lin-vel 1.2 0 0 --ang-vel 0 0 3 --seconds 4 \
		--checkpoint runs/quickstart/hybrid.ckpt --compare-sim --out reports/quickstart/bracket.json \
		--render reports/quickstart/bracket.html --overwrite
	@# where the model stands against just running PyBullet on meshes new to it (docs/performance.md)
	$(PYTHON) benchmarks/frontier.py --sets pybullet --meshes 12 --pushes 5 --one-meshes 1 --one-mesh-pushes 64 \
		--predictor quickstart=runs/quickstart/hybrid.ckpt --out reports/quickstart/frontier.md \
		--plot reports/quickstart/frontier.png
	@echo
	@echo "results:"
	@echo "  dataset        data/quickstart.zarr        (physdyn data info data/quickstart.zarr)"
	@echo "  model          runs/quickstart/best.ckpt, best_topple.ckpt (+ topple classifier), hybrid.ckpt (+ simulated start; logs: runs/quickstart/csv, tensorboard)"
	@echo "  test report    reports/quickstart/report.md, metrics.json, *.png, viewer.html (open in a browser)"
	@echo "  prediction     reports/quickstart/bracket.json, reports/quickstart/bracket.html (open in a browser)"
	@echo "  frontier       reports/quickstart/frontier.md, frontier.png (the model beside PyBullet at 5 steps and a step schedule, new meshes)"
	@echo
	@$(PYTHON) -c "import json; print('verdict:', json.load(open('reports/quickstart/metrics.json'))['verdict'])"
	@grep "against PyBullet at 1/120 s" reports/quickstart/frontier.md | sed 's/^/verdict: /'

test: install
	$(PYTHON) -m pytest -n $(TEST_WORKERS) --dist worksteal

test-all: install
	$(PYTHON) -m pytest -m "slow or not slow"

bench: install
	$(PYTHON) benchmarks/simulate.py
