# Two commands do everything on a fresh machine: `make demo` and `make test`.
VENV := .venv
BIN  := $(VENV)/bin

.PHONY: setup demo test bench clean

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml tools/setup.sh
	bash tools/setup.sh

demo: setup
	$(BIN)/polarbssrdf demo out/demo --overwrite

# one worker per core (at most 4: each holds a Dr.Jit process of ~1.5 GiB); a file's tests
# stay in one worker so its module fixtures are built once, and the files go out in
# collection order, the longest first (tests/conftest.py, SLOWEST_FILES)
test: setup
	$(BIN)/python -m pytest -q -n auto --maxprocesses 4 --dist loadfile --no-loadscope-reorder

bench: setup
	$(BIN)/python bench/run_all.py

clean:
	rm -rf out .pytest_cache
