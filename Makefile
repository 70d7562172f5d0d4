# Entry points. `make help` lists them.
PYTHON ?= python3.11
VENV   ?= .venv
BIN    := $(VENV)/bin
# MkDocs plugins print a banner about a future MkDocs 2 on every build; these silence it
MKDOCS := NO_MKDOCS_2_WARNING=1 DISABLE_MKDOCS_2_WARNING=true $(BIN)/mkdocs
STAMP  := $(VENV)/.installed
# the planner's kernels compiled into numba's cache, again after a change to the planner
KERNELS := $(VENV)/.kernels

.PHONY: help install kernels serve test docs lint typecheck bench openapi clean

help:  ## list the targets
	@grep -E '^[a-z-]+:.*##' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-10s %s\n", $$1, $$2}'

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	# the project's bytecode, as pip compiles an installed package's: where
	# PYTHONDONTWRITEBYTECODE is set (containers often set it) an editable install would
	# compile every module from source at each start, 0.2 s of every `scanplan plan`
	$(BIN)/python -m compileall -q planner service
	touch $(STAMP)

install: $(STAMP) $(KERNELS)  ## create .venv, install the project with its dev tools, compile the kernels

$(KERNELS): $(STAMP) $(shell find planner -name '*.py')
	# about a minute, once: the first plan then compiles nothing (`make test` needs no
	# such step: its tests compile what they use, into the same cache)
	$(BIN)/scanplan compile-kernels
	touch $(KERNELS)

kernels: $(KERNELS)  ## compile the planner's kernels (install and serve do, once and after a change)

serve: $(KERNELS)  ## start the API and its workers on the embedded default (SQLite, no Redis)
	$(BIN)/scanplan serve

test: $(STAMP)  ## run the whole test suite (lint, types, layering, documentation, tests)
	$(BIN)/ruff check planner service tests benchmarks
	$(BIN)/mypy
	$(BIN)/lint-imports
	$(MKDOCS) build --strict --site-dir site
	$(BIN)/python -m pytest -n auto --dist loadfile

docs: $(STAMP)  ## serve the documentation on http://127.0.0.1:8001/, rebuilt on every change
	$(MKDOCS) serve --dev-addr 127.0.0.1:8001

lint: $(STAMP)  ## ruff only
	$(BIN)/ruff check planner service tests benchmarks

typecheck: $(STAMP)  ## mypy --strict only
	$(BIN)/mypy

bench: $(STAMP)  ## print the benchmark figures
	$(BIN)/python benchmarks/plan_hall.py
	$(BIN)/python benchmarks/cli_startup.py

openapi: $(STAMP)  ## re-export openapi/openapi.json from the app
	$(BIN)/python -m service.openapi_export openapi/openapi.json

clean:  ## remove the virtual environment and caches
	rm -rf $(VENV) .mypy_cache .ruff_cache .pytest_cache site
