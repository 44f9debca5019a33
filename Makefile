# camcal: every target creates .venv (Python 3.13, the VFX Reference Platform
# CY2026 interpreter) on first use and installs the package with all its extras,
# at the exact versions of the lock file (pyproject.toml holds the ranges).
# Another interpreter: make test PYTHON=/path/to/python3.13
PYTHON ?= $(shell for p in python3.13 $$HOME/.pyenv/versions/3.13*/bin/python3.13 /usr/local/bin/python3.13 /usr/bin/python3.13; do \
	$$p -c 'import sys; sys.exit(sys.version_info[:2] != (3, 13))' 2>/dev/null && { echo $$p; break; }; done)
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
LOCK   := requirements/lock-py313.txt

.PHONY: test test-all test-lowest test-newest fuzz demo bench addon clean python

python:
	@test -n "$(PYTHON)" || { echo "camcal: Python 3.13 not found (tried python3.13, ~/.pyenv/versions/3.13*/bin, /usr/local/bin, /usr/bin); install it or run make PYTHON=/path/to/python3.13" >&2; exit 2; }

$(STAMP): pyproject.toml $(LOCK) | python
	@if [ -x $(PY) ] && ! $(PY) -c 'import sys; sys.exit(sys.version_info[:2] != (3, 13))'; then \
		echo "camcal: .venv is not Python 3.13; recreating it"; rm -rf $(VENV); fi
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -c $(LOCK) -e ".[all,blender,test]"
	$(PY) tests/colour/export/ocio_releases.py install $(VENV)/ocio
	touch $(STAMP)

# The tests run on every core (pytest-xdist), each test file in one worker so that its
# module fixtures are built once; serially: make test WORKERS=0
WORKERS ?= auto
XDIST   := -n $(WORKERS) --dist loadfile

test: $(STAMP)
	$(PY) -m pytest -m "not slow" -q $(XDIST)

test-all: $(STAMP)
	$(PY) -m pytest -q $(XDIST)

# The fast suite at the lowest and at the newest versions pyproject.toml allows, each in its own venv
# (.venv-lowest: requirements/lowest-py313.txt as constraints, written by requirements/lowest.py;
# .venv-newest: no constraints, upgraded to the newest releases on every run).
# A subset: make test-lowest TESTS="tests/io tests/model"
TESTS ?=
define versions_venv
	@$(1)/bin/python -m pip --version >/dev/null 2>&1 || { rm -rf $(1) && $(PYTHON) -m venv $(1); }
	$(1)/bin/python -m pip install --quiet --upgrade pip
	$(1)/bin/python -m pip install --quiet $(2) -e ".[all,blender,test]"
	$(1)/bin/python tests/colour/export/ocio_releases.py install $(1)/ocio
	@$(1)/bin/python -m pip list --format=freeze > $(1)/versions.txt
	$(1)/bin/python -m pytest -m "not slow" -q -p no:cacheprovider --continue-on-collection-errors $(XDIST) $(TESTS)
endef

test-lowest: python
	$(call versions_venv,.venv-lowest,-c requirements/lowest-py313.txt)

test-newest: python
	$(call versions_venv,.venv-newest,--upgrade --upgrade-strategy eager)

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
	rm -rf $(VENV) .venv-lowest .venv-newest demo_out build dist *.egg-info
