# Two commands on a fresh machine with Python 3.13 and 3.11 (see README):
#   make demo   - create .venv (Python 3.13, bpy 5.3.0) with the pinned packages, bake the
#                 embedded demo into out/demo/ and export it to out/demo/demo.glb (docs/gltf.md)
#   make test   - the test suite against the newest and the oldest supported Blender, side by
#                 side: every test that touches Blender on both, bpy 5.3.0 in .venv (Python 3.13)
#                 and bpy 4.2 LTS in .venv-4.2 (Python 3.11); the core tests on one or both
#                 (SUITE_NEW_MARKERS, SUITE_OLD_MARKERS; markers in pyproject.toml). Each suite builds its
#                 platform's zip and installs it into an isolated Blender user directory first.
#                 Fails if either fails; the suites' times go to out/test-times/. This is what
#                 .ci/run calls (after `make check` and `make package`).
#   make test-core - the quick loop: the tests that need no Blender, in .venv
#   make check  - ruff (lint + format check) over the repository, mypy over core/ and the import
#                 contracts (import-linter: core imports no bpy, no stage a later stage; pyproject.toml),
#                 with the versions pinned in requirements-check.txt (installed into .venv)
#   make web-deps - the three.js runtime's npm packages (web/package-lock.json: three,
#                 playwright-core, gltf-validator) into web/node_modules, when missing (`test` needs
#                 them); the browser tests drive a system Chromium (Debian: apt-get install chromium)
# PYTHON / PYTHON_OLD pick the interpreters; by default python3.13 / python3.11 on PATH or pyenv's.
PYTHON     ?= $(shell tools/find_python.sh 3.13)
PYTHON_OLD ?= $(shell tools/find_python.sh 3.11)
VENV       := .venv
VENV_OLD   := .venv-4.2
PY         := $(VENV)/bin/python
PY_OLD     := $(VENV_OLD)/bin/python
PYTEST_ARGS ?=
# pytest's own report of the slowest tests, in every suite `make test` runs
PYTEST_REPORT := --durations=25
# Every bpy test runs on both Blenders. The core tests need no Blender: the fast ones run on both
# interpreters, the heavy ones on one each, so that the two suites, run side by side, end
# together: `slow` on 5.3 (Python 3.13, numpy 2), `statistical` and `farm` on 4.2 (3.11, numpy 1.26).
SUITE_NEW_MARKERS := bpy or slow or not (statistical or farm)
SUITE_OLD_MARKERS := bpy or not slow

.PHONY: setup setup-4.2 setup-check check demo demo-web test test-new test-old test-core test-fast test-deps web-deps package oidn-weights bench clean

setup: $(VENV)/.installed
setup-4.2: $(VENV_OLD)/.installed
setup-check: $(VENV)/.check-installed

# $(1): interpreter, $(2): major.minor it must be, $(3): venv, $(4): requirements, $(5): who uses it
define make_venv
	@test -n "$(1)" || { echo "Python $(2) not found: it is needed for $(5). Install it (e.g. pyenv install $(2)) or set $(if $(filter 3.13,$(2)),PYTHON,PYTHON_OLD)=/path/to/python$(2)." >&2; exit 1; }
	@$(1) -c 'import sys; v = "%d.%d" % sys.version_info[:2]; sys.exit(0 if v == "$(2)" else "$(1) is Python " + v + ", not $(2) ($(5)); set $(if $(filter 3.13,$(2)),PYTHON,PYTHON_OLD)=/path/to/python$(2)")'
	rm -rf $(3)
	$(1) -m venv $(3)
	$(3)/bin/python -m pip install --quiet --upgrade pip
	$(3)/bin/python -m pip install --quiet -r $(4)
	$(3)/bin/python -m pip install --quiet --no-deps -e .
	touch $(3)/.installed
endef

$(VENV)/.installed: requirements.txt pyproject.toml
	$(call make_venv,$(PYTHON),3.13,$(VENV),requirements.txt,bpy 5.3.0 / Blender 5.1+)

$(VENV_OLD)/.installed: requirements-4.2.txt pyproject.toml
	$(call make_venv,$(PYTHON_OLD),3.11,$(VENV_OLD),requirements-4.2.txt,bpy 4.2 LTS / Blender 4.2-5.0)

# The check tools go into .venv beside the pinned packages (recreating .venv removes the stamp).
$(VENV)/.check-installed: $(VENV)/.installed requirements-check.txt
	$(PY) -m pip install --quiet -r requirements-check.txt
	touch $@

# All three always run; the target fails if any failed.
check: setup setup-check
	@status=0; \
	echo "== ruff check ."; $(PY) -m ruff check . || status=1; \
	echo "== ruff format --check ."; $(PY) -m ruff format --check . || status=1; \
	echo "== mypy core"; $(PY) -m mypy core || status=1; \
	echo "== lint-imports (contracts: pyproject.toml [tool.importlinter])"; $(VENV)/bin/lint-imports --no-cache || status=1; \
	exit $$status

demo: setup
	$(PY) tools/demo.py --out out/demo
	@$(MAKE) --no-print-directory demo-web

# The exported demo.glb rendered by the three.js runtime in headless Chromium (web/test/render.mjs)
# to out/demo/preview_web.png, when a Chromium is on the machine; else how to get one.
demo-web: web-deps
	@if node web/test/render.mjs --check >/dev/null 2>&1; then \
	  node web/test/render.mjs out/demo/demo.glb out/demo/preview_web.png; \
	else \
	  echo "demo: no Chromium for the web preview (out/demo/preview_web.png): install Debian's chromium (sudo apt-get install chromium) or set HHD_CHROMIUM=/path/to/chromium, then make demo-web"; \
	fi

# Both suites always run, side by side (most tests use one core: together they keep both busy);
# the 4.2 suite's output follows the 5.3 suite's. The target fails if either failed.
test: setup setup-4.2 test-deps web-deps
	@status=0; rm -rf out/test-times; mkdir -p out/test-times; start=$$(date +%s); \
	echo "== bpy 4.2 LTS (Python 3.11), in the background: $(PY_OLD) -m pytest -m \"$(SUITE_OLD_MARKERS)\""; \
	( $(PY_OLD) -m pytest -q -m "$(SUITE_OLD_MARKERS)" $(PYTEST_REPORT) $(PYTEST_ARGS) \
	  > out/test-times/bpy-4.2.log 2>&1; echo $$? > out/test-times/bpy-4.2.status ) & old=$$!; \
	echo "== bpy 5.3.0 (Python 3.13): $(PY) -m pytest -m \"$(SUITE_NEW_MARKERS)\""; \
	$(PY) -m pytest -q -m "$(SUITE_NEW_MARKERS)" $(PYTEST_REPORT) $(PYTEST_ARGS) || status=1; \
	echo "== bpy 5.3.0 suite: $$(( $$(date +%s) - start )) s"; \
	wait $$old; cat out/test-times/bpy-4.2.log; \
	test "$$(cat out/test-times/bpy-4.2.status)" = 0 || status=1; \
	$(PY) tools/test_times.py --wall $$(( $$(date +%s) - start )) || status=1; \
	exit $$status

# What both suites would otherwise fetch at once: the running platform's wheels and OIDN's weights.
test-deps: setup
	$(PY) tools/fetch_wheels.py --platform $$($(PY) tools/build_extension.py --print-platform)
	$(PY) tools/fetch_oidn_weights.py

# npm ci when web/node_modules is missing or older than the lock file (the runtime's pinned packages)
web-deps: web/node_modules/.package-lock.json

# (without npm: a warning, and the browser tests skip saying so; under CI they fail)
web/node_modules/.package-lock.json: web/package-lock.json web/package.json
	@if command -v npm >/dev/null; then \
	  echo "cd web && npm ci"; (cd web && npm ci --no-audit --no-fund) && touch $@; \
	else \
	  echo "web-deps: npm not found: the browser tests of the three.js runtime need Node.js and npm (apt-get install nodejs npm)" >&2; \
	fi

test-new: setup
	$(PY) -m pytest -q -m "$(SUITE_NEW_MARKERS)" $(PYTEST_ARGS)

test-old: setup-4.2
	$(PY_OLD) -m pytest -q -m "$(SUITE_OLD_MARKERS)" $(PYTEST_ARGS)

test-core: setup
	$(PY) -m pytest -q -m "not bpy" $(PYTEST_ARGS)

test-fast: setup
	$(PY) -m pytest -q -m "not (slow or statistical or farm or install)" $(PYTEST_ARGS)

package: setup
	$(PY) tools/build_extension.py --output-dir dist

# OIDN's RTLightmap weights into oidn_weights/ (also done by every package build)
oidn-weights: setup
	$(PY) tools/fetch_oidn_weights.py

bench: setup
	$(PY) bench/encoder.py

# docs/results.md and the README's headline table from bench/results/*.json (--check: up to date?)
.PHONY: results
results: setup
	$(PY) tools/results_doc.py

clean:
	rm -rf $(VENV) $(VENV_OLD) dist out build wheels *.egg-info .pytest_cache .ruff_cache .mypy_cache oidn_weights/*.tza
