# dualcal: the two set-up commands are `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test docs bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[report,fleet,video,test,docs,app,kalibr]'
	$(BIN)/python -m compileall -q src    # as a non-editable install would: start-up without compiling
	touch $(STAMP)

# Render a small synthetic wide+tele photo set, detect, calibrate, evaluate, report.
demo: $(STAMP)
	mkdir -p out/demo
	$(BIN)/dualcal synth out/demo/data --preset note8 --views 13 --seed 0 --scale 0.25
	$(BIN)/dualcal calibrate out/demo/data/photos --board 8x5 --square 30 -o out/demo/calib.json
	$(BIN)/dualcal evaluate out/demo/calib.json -o out/demo/eval.json
	$(BIN)/dualcal report out/demo/calib.json --eval out/demo/eval.json -o out/demo/report.html
	@echo "demo written to out/demo/ (calib.json, eval.json, report.html)"

test: $(STAMP)
	$(BIN)/python -m pytest -q -n auto    # one worker per core (pytest-xdist)

# The documentation site, static HTML that works offline (open out/site/index.html); strict: a warning fails it.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 DISABLE_MKDOCS_2_WARNING=true OPENBLAS_NUM_THREADS=1 $(BIN)/mkdocs build --strict
	@echo "documentation written to out/site/ (open out/site/index.html)"

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_calibrate.py
	$(BIN)/python benchmarks/bench_detect.py
	$(BIN)/python benchmarks/bench_undistort.py
	$(BIN)/python benchmarks/bench_startup.py

clean:
	rm -rf $(VENV) out .pytest_cache
