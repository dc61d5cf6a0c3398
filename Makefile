# Two commands on a fresh clone: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEMO_DIR ?= demo_out

.PHONY: demo demo-full test test-fast docs lint bench clean

$(STAMP): pyproject.toml
	test -d $(VENV) || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	# The CPU wheel of torch first, pinned, so nothing pulls the CUDA build.
	$(BIN)/pip install --quiet "torch==2.13.0" || $(BIN)/pip install --quiet "torch>=2.3,<3" --index-url https://download.pytorch.org/whl/cpu
	$(BIN)/pip install --quiet -e ".[dev]"
	touch $(STAMP)

# DEMO_DIR is the demo's own scratch folder: a rerun replaces its files (--force)
demo: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(BIN)/python -m tensegrity_sr.demo --out $(DEMO_DIR) --force

demo-full: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(BIN)/python -m tensegrity_sr.demo --full --out $(DEMO_DIR)_full --force

# tests/unit: fast checks (seconds each); tests/accuracy: seeded end-to-end identification and
# discovery. Tests marked slow stay out of both (run them with `pytest -m slow`). The files
# run in two processes (pytest-xdist; a file's tests share one, so its fixtures are built once),
# in the order given (not by test count): the long accuracy files first, so that the many
# short unit files fill the end. mypy checks
# the types beside them ([tool.mypy] in pyproject.toml; its report is printed after the
# tests'); either failing fails the target.
test: $(STAMP)
	@$(BIN)/python -m mypy > $(VENV)/mypy.log 2>&1 & types=$$!; \
	$(BIN)/python -m pytest -q -n 2 --dist loadfile --no-loadscope-reorder tests/accuracy tests/unit; tests=$$?; \
	wait $$types; typed=$$?; echo "mypy: $$(tail -n 1 $(VENV)/mypy.log)"; \
	if [ $$typed -ne 0 ]; then cat $(VENV)/mypy.log; fi; \
	[ $$tests -eq 0 ] && [ $$typed -eq 0 ]

test-fast: $(STAMP)
	$(BIN)/python -m pytest -q tests/unit

docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict -d site

lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP)
	$(BIN)/pip install --quiet -e ".[bench]"  # mujoco[sysid] for the comparison in bench_identify
	$(BIN)/python benchmarks/bench_generate.py
	$(BIN)/python benchmarks/bench_identify.py

clean:
	rm -rf $(VENV) $(DEMO_DIR) $(DEMO_DIR)_full build site *.egg-info
