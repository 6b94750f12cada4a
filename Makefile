# Two entry points, each self-contained on a fresh Debian-like machine:
#   make quickstart   install the package, then run the main job (predict, simulate, train, verdicts; ~6 min on 2 cores)
#   make test         install the package with the test tools, Ray and the example plugin, then run the test suite
PYTHON ?= python3
SUDO := $(shell [ "$$(id -u)" = "0" ] || echo sudo)
WORKERS ?= 2
# The default suite on two pytest-xdist workers: 4:17 one at a time on the 2-core machine, under 3 minutes on two.
TEST_WORKERS ?= 2

.PHONY: install install-dev system-deps quickstart test test-all bench docs

system-deps:
	@# open3d needs libusb-1.0 to import.
	@if command -v apt-get >/dev/null && ! ldconfig -p | grep -q libusb-1.0; then \
		$(SUDO) apt-get update -qq && $(SUDO) apt-get install -y -qq libusb-1.0-0; fi

install: system-deps
	@# torch first and exactly: the local CPU build; a newer torch would pull GBs of CUDA wheels.
	$(PYTHON) -m pip install -q torch==2.13.0
	@# the package and what it needs at run time: all `make quickstart` installs
	$(PYTHON) -m pip install -q -e .

install-dev: install
	@# what the test suite adds: pytest and its plugins, Ray (the scale-out tests)...
	$(PYTHON) -m pip install -q -e ".[dev,ray]"
	@# ... and the example encoder plugin, so the tests train it beside the built-ins (no deps: torch stays put).
	$(PYTHON) -m pip install -q --no-deps --no-build-isolation -e plugins/physdyn-dgcnn

QS_DATA := data/quickstart_hull_small.zarr
QS_RUN := runs/quickstart_fast
QS_OUT := reports/quickstart

quickstart: install
	@# The main job, re-runnable: finished steps are kept, an interrupted simulation resumed.
	@# 1. The example mesh (a bracket, in mm) with the shipped default (`fast`), no training; PyBullet's run beside it.
	physdyn predict examples/meshes/bracket_mm.obj --scale 0.001 --lin-vel 1.2 0 0 --ang-vel 0 0 3 --seconds 4 \
		--compare-sim --out $(QS_OUT)/bracket.json --render $(QS_OUT)/bracket.html --overwrite
	@# 2. A small store: 300 procedural shapes x 8 pushes, 256-point hull_surface clouds (what `fast` reads).
	@if physdyn data info $(QS_DATA) >/dev/null 2>&1; then echo "$(QS_DATA) exists; kept"; \
	else physdyn simulate --config configs/data/quickstart_hull_small.yaml --out $(QS_DATA) --workers $(WORKERS) \
		$$([ -d $(QS_DATA) ] && echo --resume); fi
	physdyn data info $(QS_DATA)
	@# 3. The shipped default's recipe on it, small (docs/model-card.md, "fast"): the contact prior (nothing to
	@# train: `fit` writes it), a PointNet topple classifier and a PointNet correction of where pushes end.
	physdyn recipe fast --data $(QS_DATA) --out $(QS_RUN) --set topple.steps=300 --set topple.seeds=[0] \
		--set correction.steps=300 --set correction.batch=256 --set correction.seeds=[0] --set model.name=quickstart
	@# 4. Its verdicts: against Coulomb sliding on the store's test split, and against PyBullet on meshes new
	@# to it (a small run of docs/performance.md's frontier), the shipped `fast` beside it.
	physdyn test --checkpoint $(QS_RUN)/model.ckpt --data $(QS_DATA) --out $(QS_OUT) --overwrite
	$(PYTHON) benchmarks/frontier.py --sets pybullet --meshes 12 --pushes 5 --one-meshes 1 --one-mesh-pushes 64 \
		--predictor quickstart=$(QS_RUN)/model.ckpt --predictor fast=fast \
		--out $(QS_OUT)/frontier.md --plot $(QS_OUT)/frontier.png
	@echo
	@echo "results:"
	@echo "  prediction     $(QS_OUT)/bracket.json, bracket.html (the shipped fast beside PyBullet; open in a browser)"
	@echo "  dataset        $(QS_DATA)   (physdyn data info $(QS_DATA))"
	@echo "  model          $(QS_RUN)/model.ckpt (each stage's checkpoint beside it: motion/, topple.ckpt, correction.ckpt)"
	@echo "  test report    $(QS_OUT)/report.md, metrics.json, *.png, viewer.html (open in a browser)"
	@echo "  frontier       $(QS_OUT)/frontier.md, frontier.png (quickstart and the shipped fast beside PyBullet, new meshes)"
	@echo
	@$(PYTHON) -c "import json; print('verdict:', json.load(open('$(QS_OUT)/metrics.json'))['verdict'])"
	@grep "against PyBullet at 1/120 s" $(QS_OUT)/frontier.md | sed 's/^/verdict: /'

test: install-dev
	$(PYTHON) -m pytest -n $(TEST_WORKERS) --dist worksteal

test-all: install-dev
	$(PYTHON) -m pytest -m "slow or not slow"

bench: install
	$(PYTHON) benchmarks/simulate.py

# The documentation site, into site/ (open site/index.html). --strict: a broken link or anchor, a missing page
# or an API reference that does not resolve fails the build. The CLI pages are generated from the parser.
docs: install
	$(PYTHON) -m pip install -q -e ".[docs]"
	NO_MKDOCS_2_WARNING=1 DISABLE_MKDOCS_2_WARNING=true $(PYTHON) -m mkdocs build --strict --site-dir site
