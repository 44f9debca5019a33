# camcal: every target creates .venv (Python 3.13, the VFX Reference Platform
# CY2026 interpreter) on first use and installs the package with all its extras.
# Another interpreter: make test PYTHON=/path/to/python3.13
PYTHON ?= $(shell for p in python3.13 $$HOME/.pyenv/versions/3.13*/bin/python3.13 /usr/local/bin/python3.13 /usr/bin/python3.13; do \
	$$p -c 'import sys; sys.exit(sys.version_info[:2] != (3, 13))' 2>/dev/null && { echo $$p; break; }; done)
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: test test-all fuzz demo bench addon clean python

python:
	@test -n "$(PYTHON)" || { echo "camcal: Python 3.13 not found (tried python3.13, ~/.pyenv/versions/3.13*/bin, /usr/local/bin, /usr/bin); install it or run make PYTHON=/path/to/python3.13" >&2; exit 2; }

$(STAMP): pyproject.toml | python
	@if [ -x $(PY) ] && ! $(PY) -c 'import sys; sys.exit(sys.version_info[:2] != (3, 13))'; then \
		echo "camcal: .venv is not Python 3.13; recreating it"; rm -rf $(VENV); fi
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[blender,plates,test]"
	$(PY) tests/colour/export/ocio_releases.py install $(VENV)/ocio
	touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -m "not slow" -q

test-all: $(STAMP)
	$(PY) -m pytest -q

# Every reader against mutated and random files, minutes (make test runs the quick profile);
# more examples per reader: make fuzz CAMCAL_FUZZ_EXAMPLES=10000
CAMCAL_FUZZ_EXAMPLES ?= 1500
fuzz: $(STAMP)
	CAMCAL_FUZZ=long CAMCAL_FUZZ_EXAMPLES=$(CAMCAL_FUZZ_EXAMPLES) $(PY) -m pytest -q tests/fuzz

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
