# vgr: the two set-up commands are `make demo` and `make test`; both build .venv on first use.
SHELL := /bin/bash
PY ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-$(shell cat pyproject.toml | sha1sum | cut -c1-12)

.PHONY: templates install sysdeps demo test lint bench golden clean

install: $(STAMP)

# Debian libraries that the open3d-cpu wheel needs at import time (libusb) and OpenMP (libgomp), and
# the C compiler tools/build_tf2_msgs.py builds ROS 2's tf2_msgs with (build-essential).
sysdeps:
	@if ! ldconfig -p | grep -q 'libusb-1.0.so.0' || ! ldconfig -p | grep -q 'libgomp.so.1' \
	    || ! command -v gcc >/dev/null || ! command -v g++ >/dev/null; then \
	  if [ "$$(id -u)" = 0 ]; then \
	    echo "installing Debian packages libusb-1.0-0 libgomp1 build-essential"; \
	    export DEBIAN_FRONTEND=noninteractive; \
	    apt-get update -qq && apt-get install -y -qq --no-install-recommends libusb-1.0-0 libgomp1 build-essential >/dev/null; \
	  else \
	    echo "please run: sudo apt-get install libusb-1.0-0 libgomp1 build-essential" >&2; exit 1; \
	  fi; \
	fi

$(STAMP): pyproject.toml | sysdeps
	@test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[dev,realsense,ros2]"
	$(BIN)/python tools/build_tf2_msgs.py  # /tf's message type, which has no wheel (nothing to do in a ROS 2 install)
	@rm -f $(VENV)/.installed-* && touch $@

demo: install
	$(BIN)/vgr run recipes/eye_in_hand_dock.yaml
	@echo "vgr is in $(BIN): 'source $(BIN)/activate' puts it on PATH"

test: install
	$(BIN)/python -m pytest

lint: install
	$(BIN)/ruff check . && $(BIN)/ruff format --check .

# Regenerate the golden recordings that CI replays (after an intended change of outputs).
golden: install
	rm -f recordings/*.mcap  # vgr never replaces a file: the goldens are made anew on purpose here
	$(BIN)/vgr run recipes/demo.yaml -p source.n_points=400 -p source.frames=10 --record recordings/demo.mcap --no-progress
	$(BIN)/vgr run recipes/sim_capture.yaml -p camera.intrinsics.width=160 -p camera.intrinsics.height=120 \
	  -p camera.publish_depth=false -p start.count=2 --record recordings/sim_capture.mcap --no-progress
	@for r in eye_in_hand_dock eye_to_hand_dock dual_dock planar_assembly; do \
	  $(BIN)/vgr run recipes/$$r.yaml --record recordings/$$r.mcap --no-progress || exit 1; done
	$(BIN)/python tests/cell/golden_cycle.py recordings/cell_service_cycle.mcap

# Teach the guidance scenarios: run each teach recipe, make its matcher template from the capture.
TEACH := eye_in_hand eye_to_hand planar_assembly
templates: install
	@mkdir -p runs
	@for t in $(TEACH); do \
	  rm -f runs/teach_$$t.mcap && \
	  $(BIN)/vgr run recipes/teach/$${t}_teach.yaml --record runs/teach_$$t.mcap --no-progress && \
	  $(BIN)/vgr template make --from-recording runs/teach_$$t.mcap --name $$t -o recipes/templates || exit 1; \
	done

# Benchmarks: each benchmarks/*.py script (bench_*.py are their helpers) writes benchmarks/results/<name>.json.
# `make bench` runs them all, one after the other (long); `make bench-NAME` runs one, e.g.
# `make bench-record_replay BENCH_ARGS=--quick`. Timing figures need a quiet machine.
BENCHMARKS := $(sort $(basename $(notdir $(filter-out benchmarks/bench_%.py,$(wildcard benchmarks/*.py)))))
bench: install
	@set -e; for b in $(BENCHMARKS); do echo "== benchmarks/$$b.py"; PYTHONPATH=. $(BIN)/python benchmarks/$$b.py; done

bench-%: install
	PYTHONPATH=. $(BIN)/python benchmarks/$*.py $(BENCH_ARGS)

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache .hypothesis runs
