# hptvsim: the two commands of the README are `make run` and `make test`.
# Each sets everything up from a fresh clone (virtual environment, packages) and then runs.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
# pytest workers: the machines this runs on have 2 cores
WORKERS ?= 2

.PHONY: run test test-slow lint typecheck unit bench bench-quick fmus dt-pipeline reproduce setup system-deps clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	# torch first and exactly: a looser spec anywhere would pull several GB of CUDA wheels
	$(BIN)/python -m pip install --quiet "torch==2.13.0"
	# ...and named again beside the extras, so that nothing torch-based (torchrl, benchmarl,
	# torchvision) can move it
	$(BIN)/python -m pip install --quiet "torch==2.13.0" -e ".[all,dev]"
	touch $(STAMP)

setup: $(STAMP)

# System packages the tests need (a clean CI machine has none of them): Debian's Chromium for
# the browser tests (never a browser downloaded by a test tool), gcc for the FMU and C kernels,
# Debian's PostgreSQL server programs, from which the database tests start throwaway clusters of
# their own (initdb into a temporary folder, as the postgres user when run as root), MinGW-w64 to
# cross-compile the FMUs' Windows DLLs and Wine to load and run them.
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
system-deps:
	@command -v chromium >/dev/null 2>&1 && command -v gcc >/dev/null 2>&1 && \
		ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 && \
		command -v x86_64-w64-mingw32-gcc >/dev/null 2>&1 && test -x /usr/lib/wine/wine64 || { \
		$(SUDO) apt-get update -qq && \
		DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends \
			chromium gcc postgresql gcc-mingw-w64-x86-64 wine64; }

run: setup
	$(BIN)/hptvsim serve

lint: setup
	$(BIN)/ruff check hptvsim tests
	$(BIN)/ruff format --check hptvsim tests

typecheck: setup
	$(BIN)/mypy

# HPTVSIM_REQUIRE_POSTGRES=1: the PostgreSQL tests fail, never skip, when PostgreSQL is missing;
# --durations: the log names the slowest tests (the default suite must stay well under 15 min)
unit: setup system-deps
	HPTVSIM_REQUIRE_POSTGRES=1 $(BIN)/pytest -n $(WORKERS) --durations=25

test: lint typecheck unit

# The paper's section V on the pursuit game (configs/reproduce/section5.toml): 27 runs of
# 150k env steps, two side by side, 3 DT steps on the base runs (Figs. 14-17), then
# docs/reproduction.md. Many hours on 2 cores: stop it any
# time and run it again to go on (finished runs are kept, killed ones resume; finished runs'
# results are archived in docs/reproduction/results/, committed, so a fresh clone skips them).
reproduce: setup
	$(BIN)/hptvsim reproduce

test-slow: setup system-deps
	HPTVSIM_REQUIRE_POSTGRES=1 $(BIN)/pytest -n $(WORKERS) -m slow --durations=25

BENCHES := dynamics cosim sensors world env train dt episode

bench: setup
	@for b in $(BENCHES); do echo; $(BIN)/hptvsim bench $$b || exit 1; done

bench-quick: setup
	@for b in $(BENCHES); do echo; $(BIN)/hptvsim bench $$b --quick || exit 1; done

fmus: setup
	$(BIN)/hptvsim fmu build

# The offline stage of ETFDU in one command, as in the paper: the shipped MAISAC pursuers play the
# shipped MAISAC evader on the target scenario (200 expert episodes of up to 1200 steps, the
# length the shipped policies were trained and evaluated at), one DT per pursuer learns from them
# (configs/dt/target.toml, 3000 updates), and the DTs play the same evader over 100 seeded
# episodes; Figs. 14-17. About 1.5 hours on 2 cores; re-run to resume.
dt-pipeline: setup
	$(BIN)/hptvsim dt pipeline --out hptvsim-out/dt-target --pursuers maisac-pursuers \
		--evader maisac-evader --max-steps 1200 --target q50 --target q90

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache hptvsim-out
