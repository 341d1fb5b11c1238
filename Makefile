# Two commands do all the set-up on a fresh machine with Python and make:
#   make demo   virtual environment, install, run the built-in study
#   make test   virtual environment, install with the test extras, run the whole suite on both cores
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python

.PHONY: demo test bench clean

# pip as the venv brings it (no self-upgrade: seconds, and nothing here needs a newer one);
# no byte-compiling of every installed module at install time: Python compiles what it
# imports, once, on first use, into the venv (so the runs below let it write its bytecode
# even where PYTHONDONTWRITEBYTECODE is set: without it every process, each worker too,
# would compile numpy, scipy, pandas and matplotlib from source again)
PIP    := $(PY) -m pip install --quiet --no-compile --disable-pip-version-check

# Where requirements/ holds pinned files for this Python (tools/lock.py --fits: CPython 3.11
# on x86-64 Linux), every package comes by its wheel's address and hash, with no resolution
# over the package indexes (7 s of a 13 s install): pip puts uv (the installer, pinned too)
# into the venv, uv fetches and unpacks the dependencies in parallel (pip itself, as the venv
# would bring it, and setuptools with them; the test extras with $(1) "[test]"), then mtplan
# itself, editable, built with that setuptools. Where that fails (no uv for this system, the
# wheels' host out of reach), and elsewhere, where this Python's own pip can
# install into the venv (pip >= 22.3, --python), pip resolves pyproject.toml's ranges: the
# dependencies in one pip, mtplan itself (--no-deps: its build in an isolated setuptools)
# in another, and pip into the venv (ensurepip) in a third, at once on both cores (they write
# disjoint files); without such a pip, one after the other with the venv's own pip.
DEPS = $$($(PYTHON) -c 'import tomllib; p = tomllib.load(open("pyproject.toml", "rb"))["project"]; print(*p["dependencies"], *(d for e in "$(1)".strip("[]").split(",") if e for d in p["optional-dependencies"][e]))')
HOSTPIP := $(PYTHON) -m pip --python $(PY) install --quiet --no-compile --disable-pip-version-check
UV := $(VENV)/bin/uv pip install --quiet --python $(PY) --no-deps
LOCKED = $(wildcard requirements/*/*.txt)
define install
	$(PYTHON) -m venv --without-pip $(VENV)
	if ! $(PYTHON) -m pip --python $(PY) --version >/dev/null 2>&1; then \
		$(PY) -m ensurepip --default-pip >/dev/null && $(PIP) -e '.$(1)'; \
	elif lock=$$($(PYTHON) tools/lock.py --fits) \
			&& $(HOSTPIP) --no-deps -r $$lock/uv.txt \
			&& $(UV) --require-hashes -r $$lock/core.txt $(if $(1),-r $$lock/test.txt) \
			&& $(UV) --no-build-isolation -e .; then \
		:; \
	else \
		if [ -n "$$lock" ]; then echo "make: the pinned install failed (above);" \
			"pip resolves pyproject.toml's ranges instead" >&2; fi; \
		$(PY) -m ensurepip --default-pip >/dev/null & venvpip=$$!; \
		$(HOSTPIP) --no-deps -e . & self=$$!; \
		$(HOSTPIP) $(DEPS) && wait $$self && wait $$venvpip; \
	fi
endef

$(VENV)/.installed: pyproject.toml $(LOCKED)
	$(call install,)
	touch $@

# The suite's many processes (two workers, the study's and the sweeps' pools, the commands it
# runs) would each compile the modules they import on a fresh venv, the same ones at the same
# time (the first run of a fresh clone took 30 s longer): compiled once here instead, on both
# cores, as pip does at install by default (a file that does not compile, a package's
# deliberately broken test data, is left to Python)
SITE = $$($(PY) -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
$(VENV)/.installed-test: pyproject.toml $(LOCKED)
	$(call install,[test])
	$(PY) -m compileall -qq -j 0 $(SITE) src || true
	touch $(VENV)/.installed $@

demo: $(VENV)/.installed
	PYTHONDONTWRITEBYTECODE= $(VENV)/bin/mtplan demo

test: $(VENV)/.installed-test
	PYTHONDONTWRITEBYTECODE= $(PY) -m pytest -n 2 --dist loadfile

bench: $(VENV)/.installed
	PYTHONDONTWRITEBYTECODE= $(PY) benchmarks/bench_propagate.py

clean:
	rm -rf $(VENV) build src/*.egg-info .pytest_cache
