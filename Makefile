# The two commands of README.md, plus the pieces they are made of.
#   make demo   set up if needed, then run the main demo
#   make test   set up if needed, then ctest (gtest + pytest); non-zero on any failure
SHELL := /bin/bash
BUILD ?= build
VENV ?= .venv
JOBS ?= $(shell nproc)
export MARIONETTE_BUILD_DIR := $(abspath $(BUILD))

.PHONY: setup demo test bench clean

setup:
	@JOBS=$(JOBS) scripts/setup

demo: setup
	$(VENV)/bin/marionette demo

test: setup
	cd $(BUILD) && ctest --output-on-failure --timeout 1800 -j $(JOBS)

bench: setup
	scripts/bench

clean:
	rm -rf $(BUILD)
