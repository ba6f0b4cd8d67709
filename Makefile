# pcdof: two commands from a fresh clone.
#   make demo        - set everything up, render every bundled frame into out/demo/ (side-by-side pictures)
#   make demo-batch  - render the bundled sequence with a focus pull into out/demo-batch/ (frames and a video)
#   make test        - set everything up, run the test suite
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo demo-batch test test-slow bench stress setup sysdeps chromium clean

setup: sysdeps $(STAMP)

# open3d links against libusb-1.0; install it when missing (root: apt-get; otherwise say how).
sysdeps:
	@if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing libusb-1.0-0 (needed by open3d)"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null; \
	  else \
	    echo "open3d needs the system library libusb-1.0-0. Install it with:"; \
	    echo "    sudo apt-get install -y libusb-1.0-0"; \
	    exit 1; \
	  fi; \
	fi

# the viewer's HTML export is checked in headless Chromium by the tests (skipped when it is absent)
chromium:
	@if ! command -v chromium >/dev/null 2>&1; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing chromium (for the viewer's HTML export test)"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null \
	      || echo "chromium could not be installed; the HTML export test will be skipped"; \
	  else \
	    echo "chromium is missing; the HTML export test will be skipped (sudo apt-get install -y chromium)"; \
	  fi; \
	fi

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	@echo "compiling pcdof's kernels once, so that the first render starts at once (about half a minute on 2 cores)"
	-$(VENV)/bin/pcdof warmup
	@touch $(STAMP)

demo: setup
	$(VENV)/bin/pcdof demo -o out/demo

# data/sequence: six frames of a still scene; focus pulled from the subject (1.49 m) to the wall (3.12 m)
demo-batch: setup
	$(VENV)/bin/pcdof batch data/sequence/frames.txt -o out/demo-batch --focal-length 135 --f-number 1.4 \
	    --focus-keyframes 0:1.49,5:3.12 --easing smoothstep --video out/demo-batch/focus_pull.mp4 --fps 3
	@echo "look at out/demo-batch/focus_pull.mp4 (the video) and out/demo-batch/frame_*.png"

test: setup chromium
	$(PY) -m pytest -q

test-slow: setup
	$(PY) -m pytest -q -m slow

bench: setup
	$(VENV)/bin/pcdof bench -o out/bench

stress: setup
	$(PY) scripts/stress --cases 10000

clean:
	rm -rf $(VENV) out .pytest_cache
