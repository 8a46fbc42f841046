# Two commands set everything up on a fresh machine with Python 3.11 and make:
#   make demo   -> virtual environment, install, run the main job
#   make test   -> same set-up, run the whole test suite
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/modalctl run --scene thesis-al-cc --shape sinc --param width=18mm --param center=24mm \
		--focus-time 25ms --margin 0.5 --out demo/run
	$(BIN)/modalctl run --scene thesis-al-cc --shape sinc --param width=18mm --param center=24mm \
		--focus-time 25ms --drift 1% --damping-error 20% --snr 40 --loop closed --out demo/closed
	$(BIN)/modalctl run --scene thesis-al-cc --shape sinc --param width=18mm --param center=24mm \
		--focus-time 25ms --drift 1% --damping-error 20% --snr 40 --loop closed --learn --out demo/learned
	@echo "demo: open loop in demo/run/ (metrics.json, fields.npz, spacetime.png, modal_bars.png, voltages.png, spectrogram.png)"
	@echo "demo: closed loop on a drifted beam in demo/closed/ (the same, plus loop.png and the log)"
	@echo "demo: the same after a learning shot updated the model in demo/learned/"

# one worker per core (pytest-xdist); the slowest tests go out first (tests/conftest.py)
test: $(STAMP)
	$(BIN)/python -m pytest -q -n auto

BENCHMARKS := modes_needed decompose_speed plant_speed margin_case margin_planner thesis_table focus_time \
	identify_accuracy identify_limits identify_cycle tracking closed_loop closed_maps authority saturation stability \
	control_rate control_step protocol_speed link_rates startup plate_speed loop_update identify_speed

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[bench]'
	set -e; for b in $(BENCHMARKS); do $(BIN)/python benchmarks/$$b.py; done

clean:
	rm -rf $(VENV) demo
