# The README's two commands: `make demo` and `make test`. Both set everything up
# themselves on a fresh Debian/Ubuntu machine (root or sudo): system packages,
# a working libLLVM, the virtual environment in .venv, the project. `make docs` builds
# the documentation site the same way.

SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
STAMP := $(VENV)/.installed
PYTEST_ARGS ?=

.PHONY: demo test docs setup system system-test venv clean

demo: setup
	@mkdir -p out
	$(VENV)/bin/pointillist render scenes/default.xml -o out/default.exr --png

test: setup system-test
	$(PY) -m pytest $(PYTEST_ARGS)

# The documentation site, built with warnings as errors (as the test suite builds it); the
# notebooks run in their quick mode, their outputs cached in docs/_build/.jupyter_cache.
docs: setup
	$(VENV)/bin/sphinx-build -W --keep-going -q -b html docs docs/_build/html -d docs/_build/doctrees
	@echo "documentation: open docs/_build/html/index.html"

setup: system $(STAMP)

# System packages: python3-venv where venv is missing, and a libLLVM Dr.Jit can use.
system:
	@if ! $(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then \
		echo "pointillist needs Python >= 3.11 (found: $$($(PYTHON) --version 2>&1))" >&2; exit 2; fi
	@need=""; \
	$(PYTHON) -c 'import venv, ensurepip' 2>/dev/null || need="$$need python3-venv"; \
	$(PYTHON) pointillist/core/llvm.py --check >/dev/null 2>&1 || need="$$need libllvm19"; \
	if [ -n "$$need" ]; then \
		echo "installing system packages:$$need"; \
		$(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $$need >/dev/null; \
	fi

# System packages only the tests need: Chromium, which opens compare's report.html headless
# (tests/test_compare_html.py). Not part of `setup`: `make demo` installs no browser.
system-test:
	@if ! command -v chromium >/dev/null 2>&1 && ! command -v chromium-browser >/dev/null 2>&1; then \
		echo "installing system packages: chromium (browser test of compare's report.html)"; \
		( $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq chromium >/dev/null ) \
		|| echo "could not install chromium: tests/test_compare_html.py will skip its browser checks" >&2; \
	fi

$(STAMP): pyproject.toml
	@[ -x $(PY) ] || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	@touch $(STAMP)

clean:
	rm -rf $(VENV) out build *.egg-info docs/_build docs/api/generated
