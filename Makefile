# slamlib: `make book` builds the Jupyter Book (HTML under _build/html), `make test` runs every test.
# Both do all set-up first on a fresh Debian-like machine: system packages, the virtual environment
# (.venv, pinned by requirements.lock), slamlib installed editable with its test and book extras.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
# Generated data (the default synthetic drive) and Numba's compile cache live in the checkout, shared by
# the tests, the notebooks and the book build. (No MPLBACKEND here: a notebook kernel started with
# MPLBACKEND=Agg draws no inline figures, so the book would have none; tests/conftest.py picks Agg itself.)
export SLAMLIB_CACHE ?= $(CURDIR)/_cache
export NUMBA_CACHE_DIR ?= $(CURDIR)/_cache/numba

SYSTEM_PACKAGES := libusb-1.0-0 libvulkan1 mesa-vulkan-drivers
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

.PHONY: all setup system-packages book test lint test-unit test-notebooks bench clean mathjax browser-check browser-tools pdf lab mutate mutate-run planted

all: book

setup: system-packages $(VENV)/.installed

# open3d needs libusb-1.0 at import; offscreen rendering needs Vulkan (libvulkan1, mesa-vulkan-drivers).
system-packages:
	@missing=""; for p in $(SYSTEM_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  if command -v apt-get >/dev/null; then \
	    echo "installing system packages:$$missing"; \
	    $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $$missing >/dev/null; \
	  else echo "warning: please install$$missing with your system's package manager" >&2; fi; \
	fi

$(VENV)/.installed: pyproject.toml requirements.lock
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -c requirements.lock -e ".[test,book,cudacompile,peers,sweep,loops]"
	$(BIN)/python -m pip install -q --no-deps -c requirements.lock map-closures kiss-slam  # see pyproject's `loops`
	touch $@

# Build the book (HTML under _build/html). Each notebook's outputs come from its run stored by `make test`
# (tests/test_notebooks.py) in the execution cache; a notebook with no stored run is executed (on the embedded
# default data). The cache is dropped when any of slamlib's sources is newer, so no page shows older code's outputs.
NB_CACHE := _build/.jupyter_cache
book: setup mathjax
	@if [ -f $(NB_CACHE)/global.db ] && [ -n "$$(find slamlib pyproject.toml requirements.lock -newer $(NB_CACHE)/global.db \
	  -not -path '*/__pycache__*' -print -quit)" ]; then echo "book: slamlib changed since the stored runs; executing again"; \
	  rm -rf $(NB_CACHE); fi
	$(BIN)/jupyter-book build --all -W -n --keep-going .
	@echo "book: open _build/html/index.html"

# The whole test suite: unit tests and every notebook run to its end (tests/test_notebooks.py; each ends with assert
# cells), the notebooks' runs stored for `make book`.
test: setup lint
	$(BIN)/python -m pytest -p no:dash --durations=15 tests

# The formatter and linter ([tool.ruff] in pyproject.toml): fails on unformatted code or a lint finding.
lint: setup
	$(BIN)/ruff format --check slamlib tests benchmarks notebooks
	$(BIN)/ruff check slamlib tests benchmarks notebooks

test-unit: setup
	$(BIN)/python -m pytest -p no:dash tests --ignore=tests/test_notebooks.py

bench: setup
	$(BIN)/slamlib bench --list

# Every chapter live (widgets, FULL runs): JupyterLab on notebooks/ in the book's environment (installed on first use).
lab: setup
	@$(BIN)/python -c "import jupyterlab" 2>/dev/null || $(BIN)/python -m pip install -q -c requirements.lock jupyterlab
	$(BIN)/jupyter lab notebooks/

# Mutation testing of the core math (not in CI: slow). mutmut (installed on first use) works on a copy of slamlib/
# and tests/ (MUTATE_DIR), so the checkout is never mutated; config in pyproject.toml [tool.mutmut].
# mutmut forks a worker per mutant: GNU OpenMP (Numba's default parallel layer here) aborts after fork, so the
# workqueue layer is used. `make mutate` runs two groups and prints one table (tests/mutation/score.py):
# - MUTATE_JITTED, the modules with Numba kernels: their decorators are stripped from the copy
#   (tests/mutation/strip_jit.py) and the tests run with NUMBA_DISABLE_JIT=1, so jitted bodies are mutated and run
#   as Python (prange = range); only the kernel and map tests are selected (MUTATE_JITTED_TESTS).
# - MUTATE_PURE, plain-Python modules: the copy keeps its decorators and the tests run jitted (the pipeline and
#   reader tests call the kernels, far too slow as Python), with the whole selection of pyproject.toml.
# One group or module: make mutate-run MUTANTS='slamlib.metrics.*' [MUTATE_JIT=0|1] [MUTATE_TESTS='tests/a.py ...']
# [MUTATE_DIR=...]. Report: tests/mutation/REPORT.md.
MUTMUT_VERSION      := 3.8.1
MUTATE_DIR          ?= _build/mutate
MUTANTS             ?=
MUTATE_TESTS        ?=
MUTATE_JIT          ?= 0
MUTATE_PURE         := slamlib.resampling.* slamlib.metrics.* slamlib.geometry.* slamlib.odometry.* \
                       slamlib.sim1d.* slamlib.slam3d.* slamlib.kitti.* slamlib.contract.* slamlib.atomic.*
MUTATE_JITTED       := slamlib.noise.* slamlib.maps.* slamlib.kernels.*
MUTATE_JITTED_TESTS := tests/test_noise.py tests/test_maps.py tests/test_kernels_cpu.py
mutate: setup
	$(MAKE) --no-print-directory mutate-run MUTATE_DIR=_build/mutate-pure MUTATE_JIT=1 MUTANTS='$(MUTATE_PURE)'
	$(MAKE) --no-print-directory mutate-run MUTATE_DIR=_build/mutate-jitted MUTATE_JIT=0 MUTANTS='$(MUTATE_JITTED)' \
	  MUTATE_TESTS='$(MUTATE_JITTED_TESTS)'
	$(BIN)/python tests/mutation/score.py _build/mutate-pure/results.txt _build/mutate-jitted/results.txt
	$(BIN)/python tests/mutation/survivors.py _build/mutate-pure _build/mutate-jitted > _build/mutate-survivors.md
	@echo "every survivor with its diff: _build/mutate-survivors.md"
	$(BIN)/python tests/mutation/planted.py

# Issue 15's four bugs, planted one at a time in a copy: each must fail its unit test (also a test in the suite).
planted: setup
	$(BIN)/python tests/mutation/planted.py

mutate-run: setup
	@$(BIN)/python -c "import mutmut" 2>/dev/null || $(BIN)/python -m pip install -q -c requirements.lock mutmut==$(MUTMUT_VERSION)
	rm -rf $(MUTATE_DIR) && mkdir -p $(MUTATE_DIR)
	tar --exclude=__pycache__ -cf - slamlib tests pyproject.toml | tar -xf - -C $(MUTATE_DIR)
	[ "$(MUTATE_JIT)" = 1 ] || $(BIN)/python tests/mutation/strip_jit.py $(MUTATE_DIR)
	$(BIN)/python tests/mutation/select_tests.py $(MUTATE_DIR) $(MUTATE_TESTS)
	cd $(MUTATE_DIR) && $(if $(filter 1,$(MUTATE_JIT)),,NUMBA_DISABLE_JIT=1) NUMBA_CACHE_DIR=$(CURDIR)/$(MUTATE_DIR)/numba \
	  NUMBA_THREADING_LAYER=workqueue nice -n 19 $(CURDIR)/$(BIN)/mutmut run --max-children 2 $(MUTANTS)
	cd $(MUTATE_DIR) && $(CURDIR)/$(BIN)/mutmut results --all true > results.txt && \
	  $(CURDIR)/$(BIN)/python $(CURDIR)/tests/mutation/score.py results.txt

# MathJax 3 served from the book's own _static (sphinx `mathjax_path` in _config.yml), so pages render math
# offline: fetched once from the npm registry into book/_static/mathjax (git-ignored), only the files that
# tex-mml-chtml.js loads (its fonts, the TeX extensions it may autoload, the menu and a11y modules).
MATHJAX_VERSION := 3.2.2
MATHJAX_DIR     := book/_static/mathjax
mathjax: $(MATHJAX_DIR)/.version-$(MATHJAX_VERSION)

$(MATHJAX_DIR)/.version-$(MATHJAX_VERSION):
	@command -v npm >/dev/null || { echo "installing npm"; $(SUDO) apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq npm >/dev/null; }
	@tmp=$$(mktemp -d) && (cd $$tmp && npm pack -q mathjax@$(MATHJAX_VERSION) >/dev/null && tar xzf mathjax-$(MATHJAX_VERSION).tgz) && \
	rm -rf $(MATHJAX_DIR) && mkdir -p $(MATHJAX_DIR)/input/tex $(MATHJAX_DIR)/output/chtml/fonts && \
	cp $$tmp/package/es5/tex-mml-chtml.js $$tmp/package/LICENSE $(MATHJAX_DIR)/ && \
	cp -r $$tmp/package/es5/input/tex/extensions $(MATHJAX_DIR)/input/tex/ && \
	cp -r $$tmp/package/es5/output/chtml/fonts/woff-v2 $(MATHJAX_DIR)/output/chtml/fonts/ && \
	cp -r $$tmp/package/es5/ui $$tmp/package/es5/a11y $(MATHJAX_DIR)/ && \
	rm -rf $$tmp && touch $@ && echo "mathjax $(MATHJAX_VERSION) -> $(MATHJAX_DIR)"

# Loads every page of the built book (_build/html; BOOK_HTML=... for another) in headless Chromium (Debian's
# package, driven by Playwright) and fails on JavaScript errors, failed or off-machine requests, unrendered
# math, broken images and internal links, raw pipe tables and animations that do not play:
# tests/browser/test_book_pages.py. Run after `make book`.
browser-check: browser-tools
	BOOK_BROWSER_CHECK=1 CHROMIUM=/usr/bin/chromium $(BIN)/python -m pytest -p no:dash -p no:cacheprovider tests/browser

# Debian's Chromium and Playwright's Python package, which drives it (its own browser download cannot reach its
# host): for the browser check and the PDF.
browser-tools: setup
	@dpkg -s chromium >/dev/null 2>&1 || { echo "installing chromium"; $(SUDO) apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq chromium >/dev/null; }
	@$(BIN)/python -c "import playwright" 2>/dev/null || $(BIN)/python -m pip install -q -c requirements.lock playwright

# The whole book as one PDF, _build/pdf/book.pdf: Jupyter Book's HTML-to-PDF builder (every notebook executed, as
# `make book`), printed by Debian's Chromium (book/_ext/book_pdf.py; not in CI, which prints a small book instead).
pdf: browser-tools mathjax
	CHROMIUM=/usr/bin/chromium $(BIN)/python book/_ext/book_pdf.py . --all -n --keep-going
	@echo "pdf: _build/pdf/book.pdf"

clean:
	rm -rf _build _cache .pytest_cache
