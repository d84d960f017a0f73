# Two commands do everything on a fresh machine: `make demo` and `make test`.
VENV := .venv
BIN  := $(VENV)/bin

.PHONY: setup demo test bench clean

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml tools/setup.sh
	bash tools/setup.sh

demo: setup
	$(BIN)/polarbssrdf demo out/demo --overwrite

test: setup
	$(BIN)/python -m pytest -q

bench: setup
	$(BIN)/python bench/run_all.py

clean:
	rm -rf out .pytest_cache
