# landing-sim: `make demo` lands by vision (marker-landing), `make test` runs the test suite, `make bench` the benchmarks.
# Both set up .venv first (Python 3.12 or newer; drake >= 1.58 needs it) and check the Debian
# libraries that headless rendering needs.
SHELL := /bin/bash
VENV := .venv
STAMP := $(VENV)/.installed
SYSTEM_PACKAGES := libegl1 libgl1-mesa-dri libglib2.0-0

# The oldest Python >= 3.12 (the tested one) on PATH or under pyenv; override with `make PYTHON=/path/to/python3.12`.
PYTHON ?= $(shell for p in python3.12 python3.13 python3.14 python3 \
	$$(ls -d $${PYENV_ROOT:-$$HOME/.pyenv}/versions/3.1[2-9]*/bin/python3 2>/dev/null | sort -V); do \
	  if $$p -c 'import sys; sys.exit(sys.version_info < (3, 12))' >/dev/null 2>&1; then command -v $$p; break; fi; \
	done)

.PHONY: demo test bench clean system-deps browser

demo: $(STAMP) system-deps
	$(VENV)/bin/landing-sim run marker-landing --out results/demo

test: $(STAMP) system-deps browser
	$(VENV)/bin/python -m pytest -n auto --dist loadfile

bench: $(STAMP) system-deps
	$(VENV)/bin/python benchmarks/realtime.py
	$(VENV)/bin/python benchmarks/crhf_table5.py
	$(VENV)/bin/python benchmarks/landing_sweep.py
	$(VENV)/bin/python benchmarks/marker_ekf_mc.py
	$(VENV)/bin/python benchmarks/vision_landing.py
	$(VENV)/bin/python benchmarks/federated.py

$(STAMP): pyproject.toml
	@if [ -z "$(PYTHON)" ]; then \
	  echo "error: no Python 3.12 or newer found (drake >= 1.58 needs it). Install python3.12 and python3.12-venv," \
	       "or run make PYTHON=/path/to/python3.12" >&2; exit 1; fi
	@echo "Setting up $(VENV) with $(PYTHON)"
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet --upgrade pip
	$(VENV)/bin/python -m pip install --quiet -e '.[test]'
	@touch $(STAMP)

# Headless rendering (VTK through EGL and Mesa's software rasteriser) needs these Debian packages.
# Installs them when run as root with apt-get; otherwise says which are missing.
system-deps:
	@missing=$$(for p in $(SYSTEM_PACKAGES); do \
	  dpkg-query -W -f='$${Status}' $$p 2>/dev/null | grep -q 'install ok installed' || echo $$p; done); \
	if [ -n "$$missing" ] && command -v dpkg-query >/dev/null; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "Installing $$missing for headless rendering"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; \
	  else \
	    echo "error: headless rendering needs the Debian packages: $$missing (sudo apt-get install $$missing)" >&2; \
	    exit 1; \
	  fi; \
	fi

# Chromium for the test that opens a Meshcat recording in a real browser; the test skips, saying
# why, where it cannot be installed.
browser:
	@if ! command -v chromium >/dev/null && [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "Installing chromium for the browser test"; \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
	    || echo "note: chromium could not be installed; the browser test will be skipped"; \
	fi

clean:
	rm -rf $(VENV) results models/generated .pytest_cache
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
