# `make test` and `make demo` do all the set-up on a fresh Linux machine.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: venv test demo demo-motion lint typecheck bench clean tools

# A .venv without a working pip (a half-made one, e.g. after ensurepip was missing)
# is made again. On Debian/Ubuntu the venv module is a separate package: installed
# with apt-get when we are root.
$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' || { \
	  echo "pyethercat needs Python 3.11 or newer; $(PYTHON) is $$($(PYTHON) --version 2>&1)." \
	       "Try: make PYTHON=python3.11 $(MAKECMDGOALS)"; exit 1; }
	@if ! $(PY) -m pip --version >/dev/null 2>&1; then \
	  rm -rf $(VENV); \
	  if ! $(PYTHON) -m venv $(VENV); then \
	    rm -rf $(VENV); \
	    pkg=$$($(PYTHON) -c 'import sys; print("python3.%d-venv" % sys.version_info[1])'); \
	    if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	      echo "installing $$pkg with apt-get"; \
	      apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$pkg >/dev/null \
	        && $(PYTHON) -m venv $(VENV) || exit 1; \
	    else echo "cannot create $(VENV): install the venv module (e.g. apt-get install $$pkg)"; exit 1; fi; \
	  fi; \
	fi
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

# Outside tools some tests use: tshark (interop), xmllint (ESI corpus), ip (veth
# pairs), ping/curl (EoE end to end), chromium/chromedriver (EoE end to end, the web
# dashboard's browser tests). Installed with apt-get when missing and we are root; otherwise (or when
# apt-get fails) the tests that need them skip with a reason, and fail under CI=true.
tools:
	@missing=""; \
	command -v tshark >/dev/null 2>&1 || missing="$$missing tshark"; \
	command -v xmllint >/dev/null 2>&1 || missing="$$missing libxml2-utils"; \
	command -v ip >/dev/null 2>&1 || missing="$$missing iproute2"; \
	command -v ping >/dev/null 2>&1 || missing="$$missing iputils-ping"; \
	command -v curl >/dev/null 2>&1 || missing="$$missing curl"; \
	command -v chromium >/dev/null 2>&1 || missing="$$missing chromium"; \
	command -v chromedriver >/dev/null 2>&1 || missing="$$missing chromium-driver"; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing$$missing with apt-get"; \
	    { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; } \
	      || echo "apt-get failed: the tests that need$$missing will skip (fail under CI=true)"; \
	  else echo "missing:$$missing (not root or no apt-get): the tests that need them will skip"; fi; \
	fi

test: $(STAMP) tools
	$(PY) -m pytest -q

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests benchmarks
	$(VENV)/bin/mypy

demo: $(STAMP)
	$(PY) -m pyethercat demo

# simulated servo drives on DC follow S-curve moves; the plot goes to pyethercat-motion.png
demo-motion: $(STAMP)
	$(PY) -m pyethercat demo --motion --plot pyethercat-motion.png

bench: $(STAMP)
	for b in benchmarks/*.py; do $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info
