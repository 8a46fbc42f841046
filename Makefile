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
	$(BIN)/modalctl decompose --scene thesis-al-cc --shape sinc --param width=18mm --param center=24mm \
		--plot demo/decompose.png
	@echo "demo: picture of the decomposition in demo/decompose.png"

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python benchmarks/modes_needed.py
	$(BIN)/python benchmarks/decompose_speed.py

clean:
	rm -rf $(VENV) demo
