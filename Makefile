# lunad: the two set-up commands are `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
PREFIX ?= /opt/lunad

.PHONY: demo test lint clean install uninstall

$(PY):
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

## demo: virtual TF-Luna -> lunad serve -> live view, for a few seconds
demo: $(STAMP)
	$(VENV)/bin/lunad demo

## test: lint and the default tests, incl. a 60 s soak (bench and long soaks are opt-in)
test: $(STAMP)
	$(VENV)/bin/ruff check protocol filters sim daemon tests
	$(VENV)/bin/python -m pytest

## install: as root, install the systemd service (venv in $(PREFIX), lunad@.service); DESTDIR= stages
install:
	DESTDIR="$(DESTDIR)" PREFIX="$(PREFIX)" PYTHON="$(PYTHON)" sh systemd/install.sh install

## uninstall: as root, remove it again (keeps /etc/lunad/*.toml unless PURGE=1)
uninstall:
	DESTDIR="$(DESTDIR)" PREFIX="$(PREFIX)" PURGE="$(PURGE)" sh systemd/install.sh uninstall

lint: $(STAMP)
	$(VENV)/bin/ruff check protocol filters sim daemon tests
	$(VENV)/bin/ruff format --check protocol filters sim daemon tests

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache .hypothesis
