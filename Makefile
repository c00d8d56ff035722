# Two commands on a fresh machine with python3 and make: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp

.PHONY: install demo test docs bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)  ## create .venv and install rollbot_oc with its test tools

demo: $(STAMP)  ## the main job: writes figures and JSON into out/
	$(BIN)/rollbot-oc demo --out out

test: $(STAMP)  ## the whole test suite
	$(BIN)/python -m pytest -n 2 --dist worksteal --durations=25

docs: $(STAMP)  ## the docs site into docs/_build/html, warnings as errors (notebooks run once, then cached)
	$(BIN)/python -m sphinx -b html -W --keep-going -d docs/_build/doctrees docs docs/_build/html

bench: $(STAMP)  ## benchmarks (medians over repeated runs)
	for script in benchmarks/bench_*.py; do $(BIN)/python $$script || exit 1; done

clean:
	rm -rf $(VENV) out build *.egg-info docs/_build docs/api docs/benchmarks.md
