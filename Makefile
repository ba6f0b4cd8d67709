# pcdof: two commands from a fresh clone.
#   make demo        - set everything up, render every bundled frame into out/demo/ (side-by-side pictures)
#   make demo-batch  - render the bundled sequence with a focus pull into out/demo-batch/ (frames and a video)
#   make test        - set everything up, run the test suite
#   make docs        - build the documentation site into out/site (mkdocs --strict)
#   make blender     - Blender (bpy) in .venv-blender, so that `make bench` adds its Defocus node as a peer
# Each step says what it does, how long it took last time on a 2-core machine, and how long it took now.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
# a step that filters its output fails when the command does, not only when the filter does
SHELL  := /bin/bash
.SHELLFLAGS := -o pipefail -c

.PHONY: demo demo-batch test test-slow bench blender stress setup sysdeps chromium docs clean clean-kernels

# $(call timed,WHAT,COMMAND): run COMMAND between a line saying what it does and one saying how long it took
timed = t0=$$(date +%s); echo "==> $(1)"; $(2) && echo "==> done in $$(( $$(date +%s) - t0 )) s"
# $(call ticking,WHAT,COMMAND): the same, with a line every 15 s while COMMAND runs (steps that print little);
# the ticker stops with the step's shell, however that ends (in the ticker's subshell, $$ is that shell)
ticking = t0=$$(date +%s); echo "==> $(1)"; \
	( while sleep 15 && kill -0 $$$$ 2>/dev/null; do echo "    ... still running, $$(( $$(date +%s) - t0 )) s"; done ) & \
	tick=$$!; \
	$(2); rc=$$?; kill $$tick 2>/dev/null; wait $$tick 2>/dev/null; \
	[ $$rc = 0 ] && echo "==> done in $$(( $$(date +%s) - t0 )) s"

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
	    t0=$$(date +%s); \
	    echo "==> installing Chromium (Debian's package) for the browser tests, once: about 70 s"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium \
	      | awk '/^Setting up / { n++; if (n % 20 == 0) { print "    " n " packages set up ..."; fflush() } }'; \
	    if command -v chromium >/dev/null 2>&1; then echo "==> Chromium installed in $$(( $$(date +%s) - t0 )) s"; \
	    else echo "chromium could not be installed; the HTML export test will be skipped"; fi; \
	  else \
	    echo "chromium is missing; the HTML export test will be skipped (sudo apt-get install -y chromium)"; \
	  fi; \
	fi

$(STAMP): pyproject.toml
	@test -x $(PY) || { echo "==> creating the virtual environment $(VENV) (a few seconds)"; $(PYTHON) -m venv $(VENV); }
	@$(call ticking,installing pcdof and its dependencies into $(VENV) (about 100 s the first time),\
	  $(PY) -m pip install --progress-bar off --upgrade pip | { grep -v "^Requirement already" || true; } && \
	  $(PY) -m pip install --progress-bar off -e '.[test]' | { grep --line-buffered -E '^(Collecting|Installing|Successfully)' || true; })
	-@$(call ticking,compiling pcdof's kernels once so that the first render starts at once,$(VENV)/bin/pcdof warmup)
	@touch $(STAMP)

demo: setup
	@$(call timed,rendering the bundled frames into out/demo/ (about 10 s on 2 cores),$(VENV)/bin/pcdof demo -o out/demo)

# data/sequence: six frames of a still scene; focus pulled from the subject (1.49 m) to the wall (3.12 m)
demo-batch: setup
	$(VENV)/bin/pcdof batch data/sequence/frames.txt -o out/demo-batch --focal-length 135 --f-number 1.4 \
	    --focus-keyframes 0:1.49,5:3.12 --easing smoothstep --video out/demo-batch/focus_pull.mp4 --fps 3
	@echo "look at out/demo-batch/focus_pull.mp4 (the video) and out/demo-batch/frame_*.png"

test: setup chromium
	@$(call timed,running the test suite (about 2400 tests; about 11 minutes on 2 cores),$(PY) -m pytest -q)

test-slow: setup
	$(PY) -m pytest -q -m slow

# Blender's compositor as a benchmark peer (optional): bpy pins numpy below 2, which pcdof's OpenCV does not
# accept, so it gets an environment of its own; `make bench` uses it when it is there
BLENDER_VENV := .venv-blender
BLENDER_PY   := $(BLENDER_VENV)/bin/python
BPY          := bpy>=4.2,<5.1

bench: setup
	$(if $(wildcard $(BLENDER_PY)),PCDOF_BLENDER_PYTHON=$(abspath $(BLENDER_PY))) $(VENV)/bin/pcdof bench -o out/bench

blender:
	@test -x $(BLENDER_PY) || { echo "==> creating $(BLENDER_VENV) (bpy needs Python 3.11)"; python3.11 -m venv $(BLENDER_VENV); }
	@$(call ticking,installing Blender as a Python module (bpy) into $(BLENDER_VENV) (about 400 MB; 30 s on a fast line),\
	  $(BLENDER_PY) -m pip install --progress-bar off '$(BPY)' | { grep --line-buffered -E '^(Collecting|Installing|Successfully)' || true; })
	@echo "benchmarks add Blender's Defocus node with: export PCDOF_BLENDER_PYTHON=$(abspath $(BLENDER_PY))"

stress: setup
	$(PY) scripts/stress --cases 10000

# the documentation site: MkDocs (Material) with the API reference from the docstrings; --strict fails on a
# broken link or reference
# (the site needs pcdof's sources, not its compiled kernels: no warm-up here)
docs:
	@test -x $(PY) || { echo "==> creating the virtual environment $(VENV) (a few seconds)"; $(PYTHON) -m venv $(VENV); }
	@$(call ticking,installing pcdof with the docs extra (mkdocs; about 20 s after make setup, 80 s without),\
	  $(PY) -m pip install --progress-bar off -e '.[docs]' | { grep --line-buffered -E '^(Collecting|Installing|Successfully)' || true; })
	@$(call timed,building the documentation site into out/site/,NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict -d out/site)

clean:
	rm -rf $(VENV) $(BLENDER_VENV) out .pytest_cache

# numba's on-disk cache is keyed on each kernel's own source file: after editing a helper that a kernel of
# another module inlines, the cached kernel still holds the old helper until this clears it
clean-kernels:
	find src -name '*.nbi' -delete -o -name '*.nbc' -delete
