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

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) -e .
	touch $@

$(VENV)/.installed-test: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) -e '.[test]'
	touch $(VENV)/.installed $@

demo: $(VENV)/.installed
	PYTHONDONTWRITEBYTECODE= $(VENV)/bin/mtplan demo

test: $(VENV)/.installed-test
	PYTHONDONTWRITEBYTECODE= $(PY) -m pytest -n 2 --dist loadfile

bench: $(VENV)/.installed
	PYTHONDONTWRITEBYTECODE= $(PY) benchmarks/bench_propagate.py

clean:
	rm -rf $(VENV) build src/*.egg-info .pytest_cache
