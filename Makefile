# The two set-up commands: `make demo` and `make test`. Each creates .venv, installs torch==2.13.0 first (the CPU
# wheel this machine has on disk), then biomotion with its extras, then runs.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
DATA ?= ../shared/data
STAMP := $(VENV)/.installed

.PHONY: demo test venv browser clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e '.[validate,ml,test,distributed]'
	touch $(STAMP)

venv: $(STAMP)

# Debian's chromium serves the viewer's browser tests; without root or apt the tests that need it skip.
browser:
	@command -v chromium >/dev/null 2>&1 || { \
	    if command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
	        (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
	        || echo "warning: could not install chromium; browser tests will skip"; \
	    else echo "warning: chromium absent and apt-get unavailable; browser tests will skip"; fi; }

SUBJECT4 := $(DATA)/opencap/Subject4

# The main job: generate motion for the example person, with forces, muscles, metrics, plots and the viewer.
demo: $(STAMP)
	$(BIN)/biomotion generate --profile examples/runner_52_acl.yaml --action "running at 3.5 m/s" --seconds 3 \
	    --data-root $(DATA) --out demo-output/generated_run --overwrite
	@echo "generated motion written to demo-output/generated_run (open viewer.html in a browser)"
	$(BIN)/biomotion analyze $(SUBJECT4)/MarkerData/walking1.trc --setup $(SUBJECT4)/IK/walking1_ik_setup.xml \
	    --model $(SUBJECT4)/Models/optimized_scale_and_markers.osim \
	    --grf $(SUBJECT4)/ID/walking1_grf.mot --out demo-output/walking1 --overwrite \
	    --geometry $(DATA)/opensim-models/Geometry --geometry $(DATA)/opensim-models/Models/Rajagopal/Geometry
	@echo "demo outputs written to demo-output/walking1 (open viewer.html in a browser)"

# Lint (ruff), format check, the layers contract (import-linter, DESIGN.md), then the suite on two workers.
test: $(STAMP) browser
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -n 2 -q; status=$$?; \
	if [ $$status -eq 5 ]; then echo "pytest collected no tests"; exit 0; fi; exit $$status

clean:
	rm -rf $(VENV) demo-output .pytest_cache
