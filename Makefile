# The two commands of README.md, plus the pieces they are made of.
#   make demo       set up if needed, then run the main demo
#   make test       set up if needed, then everything: gtest, pytest (quick and slow), lint
#   make test-fast  set up if needed, then all but the long end-to-end runs (ctest -LE slow)
#   make lint       ruff, format, mypy, clang-format (scripts/lint)
#   make sanitize   the controller built with AddressSanitizer + UndefinedBehaviorSanitizer (in
#                   build-sanitize/), then the boundary's gtests and the fuzz suite against it
SHELL := /bin/bash
BUILD ?= build
VENV ?= .venv
JOBS ?= $(shell nproc)
export MARIONETTE_BUILD_DIR := $(abspath $(BUILD))

SANITIZE_BUILD ?= build-sanitize
# Every check aborts, except `enum`: recoverable so that tests/sanitize/ubsan.supp can name the
# third-party header that trips it (halt_on_error still stops on any other report). `vptr` is off:
# GCC 12 checks LCM's pointer-to-member dispatch (lcm-cpp-impl.hpp, cb_func) against the address
# of the subscription's C struct instead of the C++ subscription object (whose vtable gdb shows
# intact), and every message would stop the controller.
SANITIZE_FLAGS := -fsanitize=address,undefined -fno-sanitize=vptr -fno-sanitize-recover=all \
  -fsanitize-recover=enum -fno-omit-frame-pointer
# Eigen stops trusting malloc's alignment under ASan (its own aligned blocks, with an offset byte
# before each) while Pinocchio's library, built without ASan, uses plain malloc: a Pinocchio model
# grown in the library and freed in our inline destructors is then freed the wrong way. glibc's
# and ASan's allocators both return 16-byte blocks on x86-64, so the sanitized build keeps Eigen's
# ordinary choice.
SANITIZE_CXX_FLAGS := $(SANITIZE_FLAGS) -DEIGEN_MALLOC_ALREADY_ALIGNED=1
# Any report fails the run: ASan aborts, UBSan halts, LSan's leaks fail the exit code. ASan's
# quarantine of freed blocks is kept at 8 MB (default 256): the fuzz suite checks that 10^5
# refused messages leave the controller's memory flat, and a 256 MB quarantine fills as it runs.
SANITIZE_ENV := ASAN_OPTIONS=abort_on_error=1:detect_leaks=1:strict_string_checks=1:quarantine_size_mb=8 \
  UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1:suppressions=$(abspath tests/sanitize/ubsan.supp) \
  LSAN_OPTIONS=suppressions=$(abspath tests/sanitize/lsan.supp)

.PHONY: setup demo test test-fast lint bench sanitize clean

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

sanitize: setup
	cmake -S . -B $(SANITIZE_BUILD) -DCMAKE_BUILD_TYPE=RelWithDebInfo \
	  -DCMAKE_CXX_FLAGS="$(SANITIZE_CXX_FLAGS)" -DCMAKE_C_FLAGS="$(SANITIZE_FLAGS)" \
	  -DCMAKE_EXE_LINKER_FLAGS="$(SANITIZE_FLAGS)" -DCMAKE_SHARED_LINKER_FLAGS="$(SANITIZE_FLAGS)" \
	  -DCMAKE_PREFIX_PATH="$$($(VENV)/bin/cmeel cmake)" -DPython_EXECUTABLE=$(abspath $(VENV))/bin/python \
	  -Dpybind11_DIR="$$($(VENV)/bin/python -m pybind11 --cmakedir)" -DBoost_NO_WARN_NEW_VERSIONS=ON \
	  $$(command -v ccache >/dev/null && echo -DCMAKE_CXX_COMPILER_LAUNCHER=ccache) >/dev/null
	cmake --build $(SANITIZE_BUILD) -j $(JOBS) --target marionette-controller lcm_boundary_test
	$(SANITIZE_ENV) $(SANITIZE_BUILD)/lcm_boundary_test
	$(SANITIZE_ENV) MARIONETTE_FUZZ_CONTROLLER=$(abspath $(SANITIZE_BUILD))/marionette-controller \
	  $(VENV)/bin/python -m pytest tests/python/fuzz tests/python/controller/test_controller_boundary.py -q

clean:
	rm -rf $(BUILD)
