# Two commands on a fresh machine with Python 3.11 (see README):
#   make demo   - create .venv with the pinned packages, bake the embedded demo into out/demo/
#   make test   - the test suite (builds and installs the extension into an isolated Blender
#                 user directory first); this is what .ci/run calls
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: setup demo test test-fast package bench clean

setup: $(STAMP)

$(STAMP): requirements.txt pyproject.toml
	@$(PYTHON) -c 'import sys; assert sys.version_info[:2] == (3, 11), "Python 3.11 is required (Blender 4.2-5.0 and the bpy wheel use it); set PYTHON=/path/to/python3.11"'
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet -r requirements.txt
	$(PY) -m pip install --quiet --no-deps -e .
	touch $(STAMP)

demo: setup
	$(PY) tools/demo.py --out out/demo

test: setup
	$(PY) -m pytest -q

test-fast: setup
	$(PY) -m pytest -q -m "not slow"

package: setup
	$(PY) tools/build_extension.py --output-dir dist

bench: setup
	$(PY) bench/encoder.py

clean:
	rm -rf $(VENV) dist out build wheels *.egg-info .pytest_cache
