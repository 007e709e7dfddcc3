# gnss-citygml: `make test` runs lint and every test; `make demo` runs the main job on bundled data.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: test test-qgis demo lint bench fuzz plugin screenshots clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

lint: $(STAMP)
	$(BIN)/ruff check gnss_citygml tests benchmarks tools qgis_plugin
	$(BIN)/ruff format --check gnss_citygml tests benchmarks tools qgis_plugin
	$(BIN)/mypy gnss_citygml

# The library's tests, then the QGIS plugin's in a real headless QGIS (qgis_plugin/run-tests
# makes their environment; without QGIS it says so loudly, and in CI it fails).
test: lint
	$(BIN)/python -m pytest
	qgis_plugin/run-tests

test-qgis:
	qgis_plugin/run-tests

# The README's pictures (docs/*.png): QGIS's, and the demo's report page, rendered headless in
# the QGIS tests' environment; the tileset in CesiumJS (Chromium, npm) and QGIS's 3D view
# (Xvfb): apt-get install chromium xvfb
screenshots: demo
	qgis_plugin/run-tests --setup
	.venv-qgis/bin/python tools/qgis_screenshots.py
	.venv-qgis/bin/python tools/report_screenshot.py demo-out/report.html docs/report-page.png
	.venv/bin/python tools/tileset_screenshot.py demo-out/heights.gpkg docs/tileset-cesium.png
	xvfb-run -a .venv-qgis/bin/python tools/qgis_3d_screenshot.py demo-out/heights.gpkg \
		docs/qgis-3d-view.png

# The QGIS plugin's installable zip: dist/gnss_citygml_qgis-VERSION.zip
plugin: $(STAMP)
	$(BIN)/python tools/build_plugin.py

# The main job on the sample city bundled with the package (gnss_citygml/data/city, linked as
# examples/city) and grids (unless `gnss-citygml grids` names another copy): heights, CityJSON,
# CityGML and a table per building.
demo: $(STAMP)
	$(BIN)/gnss-citygml demo -o demo-out --overwrite

# Every reader fuzzed with at least 10,000 cases (tests/fuzz; `make test` runs a short profile),
# and every writer killed with SIGKILL 50 times at random moments (tests/test_kill9.py: a few).
fuzz: $(STAMP)
	$(BIN)/python -m pytest tests/fuzz -q -p no:cacheprovider --hypothesis-profile=fuzz \
		--hypothesis-show-statistics
	$(BIN)/python benchmarks/kill9.py --kills 50

bench: $(STAMP)
	$(BIN)/python benchmarks/raycast.py
	$(BIN)/python benchmarks/observe.py
	$(BIN)/python benchmarks/export.py
	$(BIN)/python benchmarks/geodesy.py
	$(BIN)/python benchmarks/paper_table.py
	$(BIN)/python benchmarks/startup.py
	$(BIN)/python benchmarks/report.py
	$(BIN)/python benchmarks/update.py
	if [ -x .venv-qgis/bin/python ]; then .venv-qgis/bin/python benchmarks/qgis_plugin.py; \
	else echo "benchmarks/qgis_plugin.py: no .venv-qgis (qgis_plugin/run-tests --setup makes it)"; fi

clean:
	rm -rf $(VENV) .venv-qgis qgis_plugin/.qgis-settings demo-out dist .pytest_cache .ruff_cache .mypy_cache build *.egg-info
