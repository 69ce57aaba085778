# Two commands do everything on a fresh clone (only python3 >= 3.11 and make needed):
#   make demo   create .venv, install hinfnn, reproduce the paper's study into results/paper/
#   make test   create .venv if needed, run the test suite
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# The installer: uv (pinned) installs the pinned dependencies in about 5 s once downloaded, where pip
# takes 70 s on this project's machines; pip when uv cannot be had. Neither compiles the .pyc files
# of every installed module (13,000 files, 23 s of a 27-s install: Ray, pandas, SciPy are mostly
# modules hinfnn never imports): Python writes the .pyc of the 2,200 modules the demo and the tests
# import when they are first imported (6 s, once). So the commands below write bytecode even where
# the environment says not to (PYTHONDONTWRITEBYTECODE, set on this project's machines): without .pyc
# files every process would compile its imports again, up to 6 s each.
UV     := uv==0.13.9
unexport PYTHONDONTWRITEBYTECODE

# franka-sim (a server speaking libfranka's protocol over MuJoCo) for the Franka loopback test
# (tests/test_franka.py): its own environment, since it pins numpy 1.26.4 and mujoco < 3.3.
FRANKA_ENV   := .franka-env
FRANKA_STAMP := $(FRANKA_ENV)/.installed
FRANKA_PINS  := franka-sim==1.1.7 pylibfranka==0.21.3

.PHONY: demo test venv bench clean franka-env

venv: $(STAMP)

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 11), "hinfnn needs Python >= 3.11, found " + sys.version.split()[0]'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet $(UV) && $(BIN)/python -m uv pip install --quiet --native-tls \
	    --python $(BIN)/python -e '.[test]' \
	  || { echo "uv failed: installing with pip"; $(BIN)/python -m pip install --quiet --upgrade pip \
	       && $(BIN)/python -m pip install --quiet --no-compile -e '.[test]'; }
	@touch $(STAMP)

franka-env: $(FRANKA_STAMP)

$(FRANKA_STAMP): $(STAMP)
	$(PYTHON) -m venv $(FRANKA_ENV)
	$(BIN)/python -m uv pip install --quiet --native-tls --python $(FRANKA_ENV)/bin/python $(FRANKA_PINS) \
	  || $(FRANKA_ENV)/bin/python -m pip install --quiet $(FRANKA_PINS)
	@touch $(FRANKA_STAMP)

demo: $(STAMP)
	$(BIN)/hinfnn reproduce --out results/paper --force

# Two pytest-xdist workers (CI and this project's machines have 2 cores); the modules whose tests
# share compiled programs and expensive fixtures stay on one worker (xdist_group marks).
test: $(STAMP) $(FRANKA_STAMP)
	$(BIN)/python -m pytest -q -n 2 --dist loadgroup

bench: $(STAMP)
	$(BIN)/python benchmarks/run.py

clean:
	rm -rf $(VENV) $(FRANKA_ENV) results .pytest_cache .hypothesis
