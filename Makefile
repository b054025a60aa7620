# The dev loop: `make check` (lint, import layers, types, docs, tests) is what CI runs (see .ci/run), before its
# install of the wheel into a fresh venv; `make test-slow` adds the long checks.
PYTHON ?= python

.PHONY: install lint imports format type test test-slow docs check

install:  ## the CPU torch and the package with every extra (drop the pin on a GPU machine)
	$(PYTHON) -m pip install "torch==2.13.0" -e ".[all]"

lint:
	ruff check .

imports:  ## the import layers of pyproject.toml's [tool.importlinter]
	lint-imports

format:
	ruff check --fix .

type:
	mypy

test:  ## the default set, about 11 minutes on 2 cores
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PYTHON) -m pytest

test-slow:  ## the slow set only: learning checks, notebooks, the two-node Ray cluster
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PYTHON) -m pytest -m slow

docs:  ## build docs/ strictly: a broken internal link or a page missing from the nav fails
	mkdocs build --strict --site-dir site

check: lint imports type docs test
