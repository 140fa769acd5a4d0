# crashnlp: every target creates .venv from nothing when it is missing.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
CLI     := $(BIN)/crashnlp

.PHONY: demo test fuzz lint docs docs-numbers identify simulate study design bench calibrate readme-figures report-check clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[test,dask]"  # the tests run studies on dask too
	$(BIN)/python -m compileall -q crashnlp  # as a regular install does; PYTHONDONTWRITEBYTECODE would leave it out
	touch $(STAMP)

demo: $(STAMP)
	$(CLI) identify problems/pickup-56kph.yaml
	$(CLI) identify problems/nhtsa-10146.yaml

simulate: $(STAMP)
	$(CLI) simulate problems/pickup-56kph.yaml
	$(CLI) simulate problems/pickup-40kph.yaml

identify: $(STAMP)
	$(CLI) identify problems/pickup-56kph.yaml
	$(CLI) identify problems/pickup-joint.yaml
	$(CLI) identify problems/paper-configuration.yaml
	$(CLI) identify problems/nhtsa-10146.yaml

design: $(STAMP)
	$(CLI) design problems/design-crush-space.yaml

study: $(STAMP)
	$(CLI) study problems/studies/pitch-bound.yaml
	$(CLI) study problems/studies/crush-space.yaml

bench: $(STAMP)
	$(BIN)/python bench/run.py

# the numbers the README and the docs quote (console blocks, crush and stop times), from the shipped
# problems run now in a scratch folder: results/docs-numbers.json, and every marked place of the pages
# rewritten from it (scripts/docs_numbers.py); tests/test_docs_numbers.py and make docs hold the pages to it
docs-numbers: $(STAMP)
	$(BIN)/python scripts/docs_numbers.py

# the intervals' out-of-sample form term: crashnlp/analysis/calibration.json from held-out predictions of a
# corpus of several generator forms (bench/calibration.py: FORMS), a table per model form, and the intervals section of results/bench.*
calibrate: $(STAMP)
	$(BIN)/python bench/calibrate.py

readme-figures: demo identify study
	$(BIN)/python scripts/readme_figures.py

# two workers, each file's tests on one of them (a module's fixtures fit once); see tests/conftest.py
test: $(STAMP)
	$(BIN)/python -m pytest -n 2 --dist loadfile

# the report of the shipped pickup's fit opened in headless Chromium (Debian's chromium, installed if
# missing: as root), its DOM and a screenshot checked; the screenshot in results/report-check/
report-check: $(STAMP)
	@command -v chromium >/dev/null || { apt-get update -q && apt-get install -y -q chromium; }
	$(BIN)/python scripts/report_check.py results/report-check

# the fuzz test of tests/test_fuzz.py with more mutations (make test runs 15 s of it); FUZZ_SEED=n for others
FUZZ_RUNS ?= 2000
FUZZ_SEED ?= 14
fuzz: $(STAMP)
	CRASHNLP_FUZZ_RUNS=$(FUZZ_RUNS) CRASHNLP_FUZZ_SEED=$(FUZZ_SEED) CRASHNLP_FUZZ_SECONDS=3600 $(BIN)/python -m pytest -s tests/test_fuzz.py

# the documentation site into site/, warnings as errors; the tutorial notebook is executed in the build
DOCS_STAMP := $(VENV)/.installed-docs
$(DOCS_STAMP): $(STAMP) pyproject.toml
	$(BIN)/pip install -q -e ".[test,docs]"
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	@test $$(wc -l < README.md) -le 200 || { echo "README.md has more than 200 lines: the guide belongs in docs/"; exit 1; }
	CRASHNLP_COMPILE=model NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

lint: $(STAMP)
	$(BIN)/ruff check crashnlp tests bench examples docs/hooks.py scripts/docs_numbers.py
	$(BIN)/ruff format --check crashnlp tests bench examples docs/hooks.py scripts/docs_numbers.py
	$(BIN)/mypy
	$(BIN)/lint-imports --no-cache  # the layers of pyproject.toml's [tool.importlinter]

clean:
	rm -rf $(VENV) .pytest_cache site
	find results -mindepth 1 -maxdepth 1 ! -name readme ! -name 'bench.md' ! -name 'bench.json' ! -name 'docs-numbers.json' ! -name 'bench-scaling.png' -exec rm -rf {} +
