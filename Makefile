# `make demo` and `make test` set everything up on a fresh machine (a .venv beside this file).
SHELL := /bin/bash
VENV := .venv
BIN := $(VENV)/bin
# qi 3.1.5 (the NAOqi SDK) on the package index: wheels for CPython 3.8-3.12 on Linux x86_64 only (checked with
# `pip download --no-deps qi==3.1.5 --python-version 3.X --only-binary=:all:`: none for 3.13, macOS, Windows or
# Linux aarch64); the project needs 3.10+. Take the first interpreter that runs and fits.
PYTHON ?= $(shell for p in python3.11 python3.12 python3.10 python3; do \
	$$p -c 'import sys; sys.exit(not (3,10) <= sys.version_info[:2] <= (3,12))' 2>/dev/null && { echo $$p; break; }; done)
SHARED ?= ../shared
# Lab Streaming Layer stays on this machine: the shared config when present, the project's otherwise.
export LSLAPICFG ?= $(abspath $(if $(wildcard $(SHARED)/lsl_api.cfg),$(SHARED)/lsl_api.cfg,config/lsl_api.cfg))
export QI_LOG_LEVEL := silent
export NAO_TRAINER_SHARED ?= $(abspath $(SHARED))

# The install: uv (from PyPI, into the venv), with pip where uv cannot. The same versions as pip's resolution
# (checked: pip freeze of both venvs); 51 s of CPU and 32 s with the bytecode pass where pip took 75 s and 78 s,
# 8 s and 10 s without it where pip took 45 s (measured 2026-12-08). UV_FLAGS: bytecode written at install, so
# that the first commands start quickly (CI passes UV_FLAGS= : the suite writes the bytecode of what it imports,
# a fraction of the 10,321 files).
UV_FLAGS ?= --compile-bytecode

.PHONY: demo test docs docs-serve bench figures clean os-packages
$(VENV)/.installed: setup.py
	@test "$$(uname -sm)" = "Linux x86_64" || { echo "error: qi (the NAOqi SDK) has wheels for Linux x86_64 only, this is $$(uname -sm): use a Linux x86_64 machine, VM or container (e.g. docker run -it python:3.11 bash)"; exit 1; }
	@test -n "$(PYTHON)" || { echo "error: needs Python 3.10, 3.11 or 3.12 (qi 3.1.5 has wheels for 3.8-3.12, the project needs 3.10+; none is on PATH): install one, e.g. sudo apt-get install python3.11 python3.11-venv (Ubuntu: the deadsnakes PPA), or pyenv install 3.11, then make demo (or make demo PYTHON=/path/to/python3.11)"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q uv || true
	if [ -x $(BIN)/uv ]; then $(BIN)/uv pip install -q --native-tls --python $(BIN)/python $(UV_FLAGS) -e '.[all,test]'; else false; fi \
	  || { echo "note: uv did not install the project; pip does (slower)"; \
	       $(BIN)/pip install -q --upgrade pip && $(BIN)/pip install -q -e '.[all,test]'; }
	touch $@

demo: $(VENV)/.installed
	$(BIN)/nao-trainer run

# espeak-ng (the speech of `--robot desktop`, an OS package): installed where we may, a hint otherwise.
os-packages:
	@command -v espeak-ng >/dev/null 2>&1 || { \
	  if command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq espeak-ng; \
	  elif command -v apt-get >/dev/null 2>&1 && sudo -n true 2>/dev/null; then sudo apt-get update -qq && sudo apt-get install -y -qq espeak-ng; \
	  else echo "note: espeak-ng is missing (--robot desktop and its tests need it): sudo apt-get install espeak-ng"; fi; }

# 4 workers on 2 cores: most tests wait on robot time, LSL streams and child processes, not the CPU
# (measured: 6 min 38 s with 4 workers against 9 min 10 s with 2, same machine and load, 2026-12-01).
# Bytecode first. The tests start some hundreds of nao-trainer processes, and where PYTHONDONTWRITEBYTECODE is
# set (as on the machine this was measured on) each one compiled the package from source again, and each
# of the 4 workers rewrote every test module's asserts again: 0.4 s of CPU per process (a 1-turn
# `nao-trainer run`: 1.3 s with the bytecode, 1.7 s without) and 3.4 s per worker (collection: 5.1 s, 1.7 s).
# compileall writes the package's; one collection with bytecode allowed writes pytest's rewritten tests.
# numba's kernels beside that collection (tools/compile_kernels.py, on the other core): compiled once into their
# on-disk cache, where 4 workers reaching them at once each compiled them (about 9 s of CPU a time).
test: $(VENV)/.installed os-packages
	$(BIN)/python -m compileall -q nao_trainer
	env -u PYTHONDONTWRITEBYTECODE $(BIN)/python tools/compile_kernels.py & kernels=$$!; \
	  env -u PYTHONDONTWRITEBYTECODE $(BIN)/python -m pytest -q --collect-only >/dev/null 2>&1; \
	  wait $$kernels  # collection errors: shown by the run
	env -u PYTHONDONTWRITEBYTECODE $(BIN)/python -m pytest -q -n 4 --dist loadfile

# The documentation site (site/): a broken link, a missing anchor or a page left out of the nav fails the build.
# The reference pages (commands, configuration keys) are generated from the code at every build.
docs: $(VENV)/.installed
	NO_MKDOCS_2_WARNING=1 PYTHONPATH=$(CURDIR) $(BIN)/mkdocs build --strict --quiet

docs-serve: $(VENV)/.installed
	NO_MKDOCS_2_WARNING=1 PYTHONPATH=$(CURDIR) $(BIN)/mkdocs serve

bench: $(VENV)/.installed
	for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) build site *.egg-info .pytest_cache
