# skyherd: `make run` flies the main job, `make test` runs the suite. Both create or refresh
# .venv in the repo root and install the project into it, so they work on a fresh clone.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.skyherd-installed
MAVPROXY_VENV := .venv-mavproxy
MAVPROXY_STAMP := $(MAVPROXY_VENV)/.installed

.PHONY: run test test-fast test-autopilots bench lint venv mavproxy clean figures

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

# MAVProxy pulls GUI packages: it lives in its own small environment, without them.
$(MAVPROXY_STAMP): Makefile
	test -x $(MAVPROXY_VENV)/bin/python || $(PY) -m venv $(MAVPROXY_VENV)
	$(MAVPROXY_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(MAVPROXY_VENV)/bin/python -m pip install --quiet --no-deps mavproxy==1.8.75 pymavlink==2.4.50 pyserial==3.5
	$(MAVPROXY_VENV)/bin/python -m pip install --quiet lxml==6.1.3 fastcrc==0.5.0
	touch $(MAVPROXY_STAMP)

venv: $(STAMP)
mavproxy: $(MAVPROXY_STAMP)

# lockstep: the flight is the same at any speed-up, so the main job runs as fast as the machine goes
run: $(STAMP)
	$(BIN)/skyherd fly --speedup 0

test: $(STAMP) $(MAVPROXY_STAMP)
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q

# The suite without the tests marked slow (flights, drills, learner runs, SITL sessions: 3 CPU s
# or more each): every package's unit tests and one 6 s end-to-end flight (the time is in the
# README). An unmarked test that spends over 30 CPU s fails (tests/conftest.py): mark it slow.
# Two pytest-xdist workers, each a session in its own network namespace (tests/conftest.py); a
# file's tests stay on one worker (--dist loadfile), so a module's fixture is built once.
# Bytecode is written (__pycache__, ignored by git) even where the environment sets
# PYTHONDONTWRITEBYTECODE: without it each worker rewrote every test module's asserts again
# (5 of its 9 CPU s of collection) and each skyherd process the tests start compiled its modules.
test-fast: $(STAMP) $(MAVPROXY_STAMP)
	$(BIN)/ruff check .
	PYTHONDONTWRITEBYTECODE= $(BIN)/python -m pytest -q -n 2 --dist loadfile -m "not slow and not autopilot"

# Opt-in: the production companion (`skyherd fly --connect`) against real autopilot builds named
# by SKYHERD_PX4_BIN, SKYHERD_ARDUCOPTER_BIN, SKYHERD_ARDUPLANE_BIN (built outside this repository;
# docs/autopilots.md), on their own physics and on skyherd's (docs/bridges.md). Run inside
# `unshare -n sh -c 'ip link set lo up; ...'`; tests whose binary is not named are skipped with the
# reason. -s prints each flight's verdict, judge checks and figures; --durations its wall time.
test-autopilots: $(STAMP)
	$(BIN)/python -m pytest -q -m autopilot -rs -s --durations=0

# the README's figures: two flights, their figures and report.html screenshots (headless
# Chromium, Debian's `chromium`) into docs/figures/ with figures.json (commands, hashes)
figures: $(STAMP)
	$(BIN)/python -m skyherd.scripts.figures

bench: $(STAMP)
	for b in bench/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

clean:
	rm -rf $(VENV) $(MAVPROXY_VENV) build *.egg-info
