# Perceptual UV — developer entry points. `make demo` and `make test` are all a new machine needs.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
SITE := $(VENV)/lib/python3.11/site-packages
STAMP := $(VENV)/.installed
PYTEST_ARGS ?=

.PHONY: setup system-libs test test-all demo extension bench clean

setup: system-libs $(STAMP) $(SITE)/perceptual_uv_repo.pth $(VENV)/node/node_modules/gltf-validator

# The Khronos glTF validator for the .glb tests (node + npm); without them those tests skip and say why.
$(VENV)/node/node_modules/gltf-validator: $(STAMP)
	-@$(PY) tests/gltf_validate.py --install

system-libs:
	@bash tools/system_libs.sh

$(STAMP): requirements.txt
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else "Python 3.11 is required (bpy 5.0.1); found " + sys.version.split()[0] + ". Set PYTHON=/path/to/python3.11")'
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt
	touch $@

# The repo root is the package `perceptual_uv`: a link named after it, put on sys.path by a .pth file.
$(SITE)/perceptual_uv_repo.pth: $(STAMP)
	mkdir -p $(VENV)/pkgroot
	ln -sfn "$(CURDIR)" $(VENV)/pkgroot/perceptual_uv
	echo "$(CURDIR)/$(VENV)/pkgroot" > $@

test: setup
	$(PY) -m pytest -m "not slow" $(PYTEST_ARGS)

test-all: setup
	$(PY) -m pytest $(PYTEST_ARGS)

demo: setup
	$(PY) -m perceptual_uv optimize tests/data/spot/spot_triangulated.obj --out out/spot_perceptual.blend --report out/spot_report.json

extension: setup
	$(PY) tools/build_extension.py

bench: setup
	@echo "Benchmarks run on demand, e.g.: $(PY) bench/trianglewise.py --model ../shared/models/spot"

clean:
	rm -rf dist build wheels out
