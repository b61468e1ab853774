# lunad: the two set-up commands are `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
PREFIX ?= /opt/lunad

.PHONY: demo test lint typecheck clean install uninstall

$(PY):
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

## demo: virtual TF-Luna -> lunad serve -> live view, for a few seconds
demo: $(STAMP)
	$(VENV)/bin/lunad demo

## test: lint, type check and the default tests, incl. a 50 s soak (bench and long soaks are opt-in)
test: $(STAMP) typecheck
	$(VENV)/bin/ruff check protocol filters sim daemon tests
	$(VENV)/bin/python -m pytest

## typecheck: mypy over the four packages (through links that give them their import names) and tests/
typecheck: $(STAMP)
	rm -rf build/typecheck && mkdir -p build/typecheck/lunad
	for p in protocol filters sim daemon; do ln -s ../../../$$p build/typecheck/lunad/$$p; done
	$(VENV)/bin/mypy build/typecheck/lunad tests

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
