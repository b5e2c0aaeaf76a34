PYTHON ?= python3
PIP ?= $(PYTHON) -m pip

.PHONY: install install-test run test bench docs-numbers

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

# measured numbers of the README and docs/ rewritten from docs/measured/ (benchmarks/doc_numbers/), then checked
docs-numbers:
	$(PYTHON) -m benchmarks.doc_numbers write
	$(PYTHON) -m benchmarks.doc_numbers check
