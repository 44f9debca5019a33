# camcal: every target creates .venv (Python 3.11) on first use and installs
# the package with all its extras into it.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: test test-all demo bench addon clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[blender,test]"
	touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -m "not slow" -q

test-all: $(STAMP)
	$(PY) -m pytest -q

demo: $(STAMP)
	$(VENV)/bin/camcal demo --out demo_out

bench: $(STAMP)
	@for f in bench/bench_*.py; do $(PY) $$f || exit 1; done

# The Blender extension zip (dist/camcal_rig-<version>.zip), validated and built
# with the blender_ext.py tool that the bpy wheel ships.
addon: $(STAMP)
	$(PY) -m camcal.blender_bridge dist

clean:
	rm -rf $(VENV) demo_out build dist *.egg-info
