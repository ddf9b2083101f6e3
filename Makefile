# The two set-up commands of the README:
#   make demo   - set up, then run the main job on the built-in bedroom scene
#   make test   - set up, then run the test suite (what .ci/run calls)
VENV ?= .venv
PY := $(VENV)/bin/python
DEMO_OUT ?= runs/demo

.PHONY: setup demo test bench clean-venv

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml scripts/setup.sh
	bash scripts/setup.sh

demo: setup
	$(VENV)/bin/rfmitsuba demo --out $(DEMO_OUT)

test: setup
	$(PY) -m pytest

bench: setup
	$(PY) -m pip install -q -e ".[torch]"
	$(VENV)/bin/rfmitsuba bench

clean-venv:
	rm -rf $(VENV)
