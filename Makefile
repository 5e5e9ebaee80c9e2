# The two commands of README.md, plus the pieces they are made of.
#   make demo       set up if needed, then run the main demo
#   make test       set up if needed, then everything: gtest, pytest (quick and slow), lint
#   make test-fast  set up if needed, then all but the long end-to-end runs (ctest -LE slow)
#   make lint       ruff, format, mypy, clang-format (scripts/lint)
SHELL := /bin/bash
BUILD ?= build
VENV ?= .venv
JOBS ?= $(shell nproc)
export MARIONETTE_BUILD_DIR := $(abspath $(BUILD))

.PHONY: setup demo test test-fast lint bench clean

setup:
	@JOBS=$(JOBS) scripts/setup

demo: setup
	$(VENV)/bin/marionette demo

test: setup
	cd $(BUILD) && ctest --output-on-failure --timeout 1800 -j $(JOBS)

test-fast: setup
	cd $(BUILD) && ctest --output-on-failure --timeout 1800 -j $(JOBS) -LE slow

lint: setup
	scripts/lint

bench: setup
	scripts/bench

clean:
	rm -rf $(BUILD)
