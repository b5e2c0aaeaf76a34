PYTHON ?= python3
PIP ?= $(PYTHON) -m pip

.PHONY: install install-test run test bench

install:
	$(PIP) install -q -e .

install-test:
	$(PIP) install -q -e ".[test]"

run: install
	campaign submit sitedata/gusev.toml

test: install-test
	$(PYTHON) -m ruff check .
	$(PYTHON) -m mypy
	$(PYTHON) -m pytest

bench: install
	$(PYTHON) -m benchmarks
