# make demo  - set up .venv; the dumbbell's table (paper Table 2) with error norms beside the
#              paper's numbers; its FMU built, co-simulated with fmpy and compared in-process
# make test  - set up .venv, run the whole test suite
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test setup clean fmu bench

setup: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m validation table dumbbell
	$(PY) -m fmu demo dumbbell --out out/fmu

# the suite starts Python subprocesses (FMU hosts, CLIs, fresh imports): with
# PYTHONDONTWRITEBYTECODE set each would compile every module from source again
test: $(STAMP)
	env -u PYTHONDONTWRITEBYTECODE $(PY) -m pytest

# work-precision against IDA, Radau and BDF, and the beam's scaling (docs/performance.md);
# benchmarks/ is not installed: run from the repository's root
bench: $(STAMP)
	$(PY) -m benchmarks precision --out docs/performance-data
	$(PY) -m benchmarks scale --out docs/performance-data --no-full-run --compiled off
	$(PY) -m benchmarks scale --out docs/performance-data/compiled --no-full-run --paths

fmu: $(STAMP)
	$(PY) -m fmu build all --out out/fmu

clean:
	rm -rf $(VENV) build *.egg-info out
