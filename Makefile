# `make bench` and `make test` do all the set-up on a fresh machine.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
BENCH_OUT ?= results/default
BUDGETS_OUT ?= results/budgets-quick
# Where the system OpenCL loader looks for drivers (it honours OCL_ICD_VENDORS too).
OPENCL_VENDORS ?= $(or $(OCL_ICD_VENDORS),/etc/OpenCL/vendors)
# OPENCL=pip: install the pip PoCL and run `make bench` on it alone (the loader shown only its
# driver file), to compare drivers; the default, auto, prefers a system driver (see $(STAMP)).
OPENCL ?= auto
ifeq ($(OPENCL),pip)
ON_DRIVER_BENCH = OCL_ICD_VENDORS="$$(echo $(CURDIR)/$(VENV)/lib/python3*/site-packages/pyopencl/.libs/pocl.icd)"
DRIVER_STAMP := $(VENV)/.pip-pocl
endif
ON_DRIVER = IBLBENCH_DEVICE= $(ON_DRIVER_BENCH)
APT_INSTALL = DEBIAN_FRONTEND=noninteractive sh -c 'apt-get install -y -q "$$0" || { apt-get update -q && apt-get install -y -q "$$0"; }'

.PHONY: bench budgets test venv clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	@# The driver: a system one where there is one; else, as root with apt-get, Debian's PoCL,
	@# built for this CPU, not the pip PoCL (1.6-2.7x slower: the README's driver table); else the
	@# pip PoCL, with a hint. OPENCL=pip forces the pip PoCL for `make bench`.
	@if [ "$(OPENCL)" = pip ]; then \
		echo "OpenCL: OPENCL=pip: installing the pip PoCL; make bench runs on it alone"; \
		$(PY) -m pip install -q -e '.[test,pocl]'; \
	elif ls $(OPENCL_VENDORS)/*.icd >/dev/null 2>&1; then \
		echo "OpenCL: system driver found in $(OPENCL_VENDORS)"; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
		echo "OpenCL: no system driver; installing Debian's pocl-opencl-icd with apt-get, because it"; \
		echo "OpenCL: builds for this CPU: the pip PoCL ran 1.6-2.7x slower (README, Drivers)"; \
		$(APT_INSTALL) pocl-opencl-icd >$(VENV)/apt.log 2>&1 || { \
			tail -3 $(VENV)/apt.log; echo "hint: apt-get could not install pocl-opencl-icd; installing the pip PoCL"; \
			$(PY) -m pip install -q -e '.[test,pocl]'; }; \
	else \
		echo "hint: no system OpenCL driver, and not root with apt-get: installing the pip PoCL, which ran"; \
		echo "hint: 1.6-2.7x slower than Debian's 'apt-get install -y pocl-opencl-icd' (README, Drivers)"; \
		$(PY) -m pip install -q -e '.[test,pocl]'; \
	fi
	@# A driver may be there and still unable to build for this CPU (the pip PoCL's LLVM 14 names
	@# CPUs newer than it 'generic', which it cannot target): then, as root on Debian, install
	@# Debian's PoCL; otherwise stop here with the reason.
	@if ! $(ON_DRIVER) $(VENV)/bin/iblbench list devices >/dev/null 2>&1; then \
		echo "OpenCL: no device here can build a kernel:"; \
		$(ON_DRIVER) $(VENV)/bin/iblbench list devices 2>&1 | sed 's/^/  /'; \
		if [ "$(OPENCL)" != pip ] && [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
			echo "OpenCL: installing Debian's pocl-opencl-icd (PoCL for this CPU) with apt-get"; \
			$(APT_INSTALL) pocl-opencl-icd >>$(VENV)/apt.log 2>&1 \
				|| { tail -5 $(VENV)/apt.log; echo "error: apt-get could not install pocl-opencl-icd"; exit 1; }; \
			IBLBENCH_DEVICE= $(VENV)/bin/iblbench list devices >/dev/null \
				|| { echo "error: still no OpenCL device that can build a kernel"; exit 1; }; \
		else \
			echo "error: install an OpenCL driver for this CPU or GPU (Debian: apt-get install pocl-opencl-icd)"; \
			exit 1; \
		fi; \
	fi
	@echo "OpenCL: $$($(ON_DRIVER) $(VENV)/bin/iblbench list devices | grep '^\*' | cut -c3-)"
	@# Optional: clang-15 compiles every kernel for two other targets (tests/test_compile_clang.py,
	@# which skips without it); as root on Debian it is installed, else a hint says so.
	@if ! command -v clang-15 >/dev/null 2>&1; then \
		if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
			echo "clang: installing Debian's clang-15 (the kernel compile test) with apt-get"; \
			$(APT_INSTALL) clang-15 >$(VENV)/apt-clang.log 2>&1 \
				|| echo "hint: apt-get could not install clang-15 ($(VENV)/apt-clang.log); the kernel compile test will skip"; \
		else \
			echo "hint: no clang-15, so the kernel compile test will skip (Debian: apt-get install clang-15)"; \
		fi; \
	fi
	touch $(STAMP)

# bench: under 10 minutes on a 2-core CPU from a clean clone, about 5 CPU-minutes in all;
# docs/measurements.md gives each part's time.  The default sweep covers every estimator that declares a part of it, the
# real-photograph scene sphere-park and the short sequence park-turn.
# perf: throughput against the roofline and the NumPy floor (about a minute here; bis and smc run
# at spp 20, Kronander's N = 20 with M = 400 candidates, with 3 repeats by default).
# OPENCL=pip on a venv made without it: add the pip PoCL.
$(VENV)/.pip-pocl: $(STAMP)
	$(PY) -m pip install -q -e '.[test,pocl]'
	touch $@

bench: $(STAMP) $(DRIVER_STAMP)
	$(ON_DRIVER_BENCH) $(VENV)/bin/iblbench run --config default --out $(BENCH_OUT)
	$(VENV)/bin/iblbench report $(BENCH_OUT)
	$(ON_DRIVER_BENCH) $(VENV)/bin/iblbench perf --out $(BENCH_OUT)/perf

# budgets: remake budgets.toml from a fresh `quick` sweep (16 seeds; under a minute here), after
# any change that moves a sample stream: `make budgets WHY="what changed"`.  The margin and
# se multiple are the ones harness/configs/quick.toml was chosen for (issue 11).
budgets: $(STAMP)
	rm -rf $(BUDGETS_OUT)
	$(VENV)/bin/iblbench run --config quick --no-progress --out $(BUDGETS_OUT)
	$(VENV)/bin/iblbench budgets $(BUDGETS_OUT) --margin 0.05 --se-multiple 3 \
		--output budgets.toml --why "$(WHY)"

# test: two pytest workers (pytest-xdist), each taking whole test files, so module fixtures and
# the fuzz summary stay in one process; the files marked slow go first (tests/conftest.py), so
# that the mutation catalogue runs beside the rest instead of at the end.  TEST_WORKERS=0 runs
# them all in this process.
TEST_WORKERS ?= 2
test: $(STAMP)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder

clean:
	rm -rf $(VENV) build *.egg-info
