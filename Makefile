# illum: two commands set up everything on a fresh machine.
#   make demo   creates .venv, installs illum with its test extras, renders stages/cornell_box.usda
#   make test   prepares .venv the same way and runs the test suite
# Both are idempotent: the install step re-runs only when pyproject.toml changes.
# The install step and `make demo` run `illum warmup` (demo: only if no warm-up finished for this
# source tree): numba compiles the kernels once into its cache (__pycache__, or $NUMBA_CACHE_DIR),
# so no render pays that on its first run.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUT    := out

.PHONY: demo test stress bench clean warmup

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	$(BIN)/illum warmup --quiet
	@touch $(STAMP)

warmup: $(STAMP)
	$(BIN)/illum warmup

demo: $(STAMP)
	$(BIN)/python -m compileall -q renderer service usd_schemas > /dev/null
	$(BIN)/illum warmup --if-needed --quiet
	@mkdir -p $(OUT)
	$(BIN)/illum render stages/cornell_box.usda -o $(OUT)/cornell_box.exr --preview $(OUT)/cornell_box.png \
		--spp 16 --stats $(OUT)/cornell_box.json
	@echo ""
	@echo "Rendered:"
	@echo "  $(abspath $(OUT)/cornell_box.exr)   (linear Rec.709, float32 EXR)"
	@echo "  $(abspath $(OUT)/cornell_box.png)   (sRGB preview)"
	@echo "  $(abspath $(OUT)/cornell_box.json)  (render statistics)"

# Byte-compile illum's own modules first: with PYTHONDONTWRITEBYTECODE set (as on many CI
# machines) every `illum` process would otherwise recompile them from source (~0.3 s each).
# Two test processes: most tests render on one thread, so the suite is one core's work
# otherwise. The Ray cluster tests share one process (xdist_group "ray", --dist loadgroup).
test: $(STAMP)
	$(BIN)/python -m compileall -q renderer service usd_schemas > /dev/null
	$(BIN)/python -m pytest -q -n 2 --dist loadgroup

stress: $(STAMP)
	ILLUM_HYPOTHESIS_PROFILE=long ILLUM_SLOW=1 $(BIN)/python -m pytest -q -m 'slow or heavy'

clean:
	rm -rf $(OUT) .pytest_cache .hypothesis
