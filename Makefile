# gnss-citygml: `make test` runs lint and every test; `make demo` runs the main job on bundled data.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: test demo lint bench clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

lint: $(STAMP)
	$(BIN)/ruff check gnss_citygml tests benchmarks
	$(BIN)/ruff format --check gnss_citygml tests benchmarks

test: lint
	$(BIN)/python -m pytest

demo: $(STAMP)
	$(BIN)/gnss-citygml demo

bench: $(STAMP)
	$(BIN)/python benchmarks/paper_table.py

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache build *.egg-info
