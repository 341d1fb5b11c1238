# make demo   a virtual environment with mtplan installed (editable), then the built-in study
# make test   the same with the test extras, then the whole suite on two workers
# uv installs where it is present; pip otherwise. Both resolve pyproject.toml's ranges.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
UV     := $(shell command -v uv)
INSTALL = $(if $(UV),$(UV) pip install --python $(PY),$(PY) -m pip install)

.PHONY: demo test clean

$(PY):
	$(PYTHON) -m venv $(VENV)

$(VENV)/.installed: pyproject.toml | $(PY)
	$(INSTALL) -e .
	touch $@

$(VENV)/.installed-test: pyproject.toml | $(PY)
	$(INSTALL) -e '.[test]'
	touch $(VENV)/.installed $@

demo: $(VENV)/.installed
	$(VENV)/bin/mtplan demo

test: $(VENV)/.installed-test
	$(PY) -m pytest -n 2 --dist loadfile

clean:
	rm -rf $(VENV) build src/*.egg-info .pytest_cache
