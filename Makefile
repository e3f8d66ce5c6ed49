# eskin: two commands set everything up on a fresh machine.
#   make demo   the whole pipeline on the built-in simulated campaign
#   make test   every test (ctest for the C++ core, pytest for the package)
SHELL := /bin/bash
, := ,
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
JOBS ?= $(shell nproc)
# Debian packages, by what needs them (each list is installed, through apt-get, only when one of
# its packages is missing):
#   make demo (and every build): a C++17 compiler and Eigen
APT_PACKAGES := build-essential libeigen3-dev
#   make test: GoogleTest (ctest), valgrind (instruction counts of benchmarks/bench_inference.py),
#   pkg-config (a test builds against the installed C++ library with it), and chromium with
#   chromium-driver (the live page of `eskin listen --web` tested in a headless browser)
APT_TEST_PACKAGES := libgtest-dev valgrind pkg-config chromium chromium-driver
#   make test's sanitizer and fuzzing leg (check-sanitizers, sanitize, fuzz): clang, its runtime
#   libraries and libFuzzer
APT_SANITIZE_PACKAGES := clang libclang-rt-14-dev libfuzzer-14-dev
# The Cortex-M4F cross toolchain and the board emulator of `make mcu` and of `make test`'s
# firmware-on-QEMU test (tests/python/test_mcu_link.py; `make demo` does not need them).
APT_MCU_PACKAGES := gcc-arm-none-eabi libnewlib-arm-none-eabi libstdc++-arm-none-eabi-newlib \
  qemu-system-arm
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
CMAKE := $(VENV)/bin/cmake
BUILD_CPP := build/cpp
BUILD_DEV := build/dev
BUILD_MCU := build/mcu

.PHONY: all deps test-deps sanitize-deps mcu-deps mcu mcu-link venv venv-test install cpp ctest pytest \
  test demo skin-demo dev devtest bench clean stubs sanitize check-sanitizers fuzz fuzz-listener \
  mutation mutation-deps mutation-diff

all: install cpp

# Python writes the bytecode of the modules it imports (into the venv and python/eskin/__pycache__,
# both ignored by git) even where the environment sets PYTHONDONTWRITEBYTECODE: without it every
# Python process of the demo and the tests compiled numpy, SciPy and scikit-learn from source again
# (3.5 s for `import scipy.signal` alone on two cores).
unexport PYTHONDONTWRITEBYTECODE

# One step of a long target: a line saying what it does, so no minute passes in silence.
step = @printf '\n==> %s\n' "$(1)"

# Installs the Debian packages of list $(1) that are missing (apt-get, with sudo when not root).
define apt_install
@missing=""; for p in $(1); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
if [ -n "$$missing" ]; then \
  echo "==> installing Debian packages:$$missing"; \
  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $$missing; \
fi
@mkdir -p build && touch $@
endef

deps: build/.deps-ok
build/.deps-ok: Makefile
	$(call apt_install,$(APT_PACKAGES))

test-deps: build/.test-deps-ok
build/.test-deps-ok: Makefile
	$(call apt_install,$(APT_PACKAGES) $(APT_TEST_PACKAGES))

sanitize-deps: build/.sanitize-deps-ok
build/.sanitize-deps-ok: Makefile
	$(call apt_install,$(APT_SANITIZE_PACKAGES))

mcu-deps: build/.mcu-deps-ok
build/.mcu-deps-ok:
	$(call apt_install,$(APT_MCU_PACKAGES))

# A virtual environment with the build tools and the package's own dependencies (what `make demo`
# needs); venv-test adds the test dependencies (pytest, hypothesis, Dask). The packages are
# installed by uv (PyPI's `uv`, itself pip-installed into the venv first): from its cache it
# installs these packages in about 2 s, where pip took about 30 s on two cores. Python compiles
# the modules it imports on first use (below: bytecode is written even where
# PYTHONDONTWRITEBYTECODE is set), instead of compiling every module of every package up front.
# pip itself is upgraded only when it is too old for the editable install of `install` (PEP 660:
# pip 21.3).
UV := $(VENV)/bin/uv
UV_PIP := $(UV) pip install --python $(PY)
venv: $(VENV)/.deps-ok
$(VENV)/.deps-ok: pyproject.toml
	$(call step,Python environment $(VENV): build tools and eskin's dependencies (uv))
	@test -x $(PY) || python3 -m venv $(VENV)
	@$(PY) -c "import pip, sys; sys.exit(tuple(map(int, pip.__version__.split('.')[:2])) < (21, 3))" \
	  || $(PIP) install --upgrade pip
	@test -x $(UV) || $(PIP) install --quiet --no-compile --progress-bar off uv
	$(UV_PIP) scikit-build-core pybind11 cmake ninja \
	  $$($(PY) -c "import tomllib; print(' '.join(tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies']))")
	@touch $@

venv-test: $(VENV)/.test-deps-ok
$(VENV)/.test-deps-ok: $(VENV)/.deps-ok
	$(call step,Python environment $(VENV): test dependencies (uv))
	$(UV_PIP) $$($(PY) -c "import tomllib; print(' '.join(tomllib.load(open('pyproject.toml', 'rb'))['project']['optional-dependencies']['test']))")
	@touch $@

# The package itself, editable: Python sources from python/, the compiled core built by scikit-build-core.
# pip -v shows scikit-build-core's CMake and Ninja output: only the build's own progress lines
# ([n/N] ..., *** ...) and pip's result are shown, and the whole log goes to build/install.log.
install: deps venv
	$(call step,building the C++ core$(,) eskin-fw-sim$(,) eskin-classify and the Python module (scikit-build-core$(,) editable install into $(VENV)))
	@mkdir -p build; set -o pipefail; \
	$(PIP) install -v --no-build-isolation --no-deps -e . 2>&1 | tee build/install.log \
	  | grep --line-buffered -E '^ *(\[[0-9]+/[0-9]+\]|\*\*\* )|^Successfully|^ERROR|error:' \
	  || { echo "the build failed; its log: build/install.log"; tail -30 build/install.log; exit 1; }

# The C++ core on its own, with its GoogleTest suite and the command-line tools.
cpp: test-deps venv
	$(CMAKE) -S . -B $(BUILD_CPP) -G Ninja -DCMAKE_BUILD_TYPE=Release -DESKIN_BUILD_TESTS=ON -DESKIN_BUILD_PYTHON=OFF >/dev/null
	$(CMAKE) --build $(BUILD_CPP) -j $(JOBS)

ctest: cpp
	cd $(BUILD_CPP) && "$(CURDIR)/$(VENV)/bin/ctest" --output-on-failure -j $(JOBS)

# mcu-deps: tests/python/test_mcu_link.py runs the firmware on QEMU (it fails under CI without it).
# The test files are shared between $(JOBS) pytest-xdist workers, each file whole on one worker
# (its module fixtures built once); no test asserts a duration, so sharing the cores is safe.
pytest: install venv-test mcu-deps
	PATH="$(CURDIR)/$(VENV)/bin:$$PATH" ESKIN_BIN_DIR="$(CURDIR)/$(BUILD_CPP)" $(PY) -m pytest -q -n $(JOBS) --dist loadfile tests/python

test: ctest pytest check-sanitizers

# The C++ tests and the libFuzzer harnesses (tests/fuzz) built by clang with AddressSanitizer and
# UndefinedBehaviorSanitizer (docs/fuzzing.md). check-sanitizers runs the tests and each harness
# for FUZZ_RUNS inputs from its seed corpus (part of `make test`); `make fuzz` runs each harness
# for FUZZ_TIME seconds and on until FUZZ_MIN_RUNS inputs, keeping its corpus in build/fuzz-corpus.
BUILD_SAN := build/sanitize
FUZZ_HARNESSES := model frame_decoder replay npy
FUZZ_RUNS ?= 2000
FUZZ_TIME ?= 60
FUZZ_MIN_RUNS ?= 100000
FUZZ_FLAGS := -rss_limit_mb=2048 -malloc_limit_mb=1024 -timeout=10 -print_final_stats=1
sanitize: deps sanitize-deps test-deps venv
	CC=clang CXX=clang++ $(CMAKE) -S . -B $(BUILD_SAN) -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
	  -DESKIN_BUILD_TESTS=ON -DESKIN_BUILD_PYTHON=OFF -DESKIN_INSTALL=OFF -DESKIN_FUZZ=ON >/dev/null
	$(CMAKE) --build $(BUILD_SAN) -j $(JOBS)

check-sanitizers: sanitize
	cd $(BUILD_SAN) && "$(abspath $(VENV))/bin/ctest" --output-on-failure -j $(JOBS)
	@for h in $(FUZZ_HARNESSES); do \
	  rm -rf $(BUILD_SAN)/fuzz-new/$$h && mkdir -p $(BUILD_SAN)/fuzz-new/$$h && \
	  echo "fuzz_$$h: $(FUZZ_RUNS) runs" && \
	  $(BUILD_SAN)/fuzz_$$h $(FUZZ_FLAGS) -seed=1 -runs=$(FUZZ_RUNS) \
	    -artifact_prefix=$(BUILD_SAN)/fuzz-new/$$h- $(BUILD_SAN)/fuzz-new/$$h tests/fuzz/corpus/$$h \
	    2>$(BUILD_SAN)/fuzz-new/$$h.log || { tail -40 $(BUILD_SAN)/fuzz-new/$$h.log; exit 1; }; \
	done

# The listener's fuzz test (hypothesis: CRC-valid frames of arbitrary field values), part of
# `make test` with a short fixed budget; `make fuzz` runs it for FUZZ_LISTENER_EXAMPLES inputs.
FUZZ_LISTENER_EXAMPLES ?= 100000
fuzz-listener: install venv-test
	ESKIN_FUZZ_EXAMPLES=$(FUZZ_LISTENER_EXAMPLES) $(PY) -m pytest -q -p no:cacheprovider \
	  --hypothesis-show-statistics tests/python/link/test_listener_fuzz.py

fuzz: sanitize fuzz-listener
	@for h in $(FUZZ_HARNESSES); do \
	  d=build/fuzz-corpus/$$h; mkdir -p $$d; \
	  run() { $(BUILD_SAN)/fuzz_$$h $(FUZZ_FLAGS) -artifact_prefix=$$d- "$$@" $$d tests/fuzz/corpus/$$h \
	    2>$$d.log || { tail -40 $$d.log >&2; exit 1; }; \
	    grep -h "^stat::number_of_executed_units" $$d.log | awk '{print $$2}'; }; \
	  n=$$(run -max_total_time=$(FUZZ_TIME)) || exit 1; \
	  if [ "$$n" -lt $(FUZZ_MIN_RUNS) ]; then \
	    m=$$(run -runs=$$(( $(FUZZ_MIN_RUNS) - n ))) || exit 1; n=$$(( n + m )); fi; \
	  echo "fuzz_$$h: $$n runs, no finding (corpus $$d, $$(ls $$d | wc -l) inputs)"; \
	done

# The inference core on a Cortex-M4F (docs/mcu.md): a small model of the demo campaign and a few
# held-out recordings (tools/mcu_case.py), the device build (cmake/arm-none-eabi.cmake,
# ESKIN_DEVICE=ON) with the model compiled in, the check of its program (no exceptions, RTTI,
# threads, or allocation on the decision path), and the run on QEMU's mps2-an386 board, which
# ends with the line "MCU: board=... parity=ok ..."; then the heap bound: the same model with an
# unbounded window must be refused at construction (exit status 4, "out of memory"); then the
# stack: the decision's need, bounded from the linked image's frames (tools/mcu_stack.py), is
# written into each program, which refuses to construct the classifier below a caller that
# leaves less (eskin-mcu-deep, exit status 5), and without that rule the stack's MPU guard stops
# the overrun (eskin-mcu-overrun, exit status 5); the MCU line ends with stack=used/size.
# Any model: `make mcu MODEL=m.eskin CAMPAIGN=held.h5` runs a user's model on a few recordings
# of each class of a held-out campaign through the same check (no heap-bound case then).
# MCU_PYTHON= (empty) skips `install` when $(PY) already imports eskin (e.g. PYTHONPATH=python).
MCU_CASE := $(BUILD_MCU)/case
MCU_PYTHON ?= install
MCU_CASE_ARGS = $(if $(MODEL),--model $(abspath $(MODEL)) --campaign $(abspath $(CAMPAIGN)))
mcu: mcu-deps $(MCU_PYTHON)
	@if [ -n "$(MODEL)$(CAMPAIGN)" ] && { [ -z "$(MODEL)" ] || [ -z "$(CAMPAIGN)" ]; }; then \
	  echo "make mcu: MODEL=m.eskin and CAMPAIGN=held.h5 go together"; exit 2; fi
	rm -rf $(MCU_CASE)
	PATH="$(CURDIR)/$(VENV)/bin:$$PATH" $(PY) tools/mcu_case.py $(MCU_CASE) $(MCU_CASE_ARGS)
	$(CMAKE) -S . -B $(BUILD_MCU) -G Ninja -DCMAKE_TOOLCHAIN_FILE=cmake/arm-none-eabi.cmake \
	  -DESKIN_DEVICE=ON -DCMAKE_BUILD_TYPE=Release \
	  -DESKIN_MCU_MODEL_HEADER=$(CURDIR)/$(MCU_CASE)/mcu_case.h >/dev/null
	$(CMAKE) --build $(BUILD_MCU)
	$(CMAKE) --build $(BUILD_MCU) --target eskin-mcu-deep eskin-mcu-overrun
	$(PY) tools/mcu_elf_check.py $(BUILD_MCU)/mcu/eskin-mcu.elf
	$(PY) tools/mcu_image_size.py $(BUILD_MCU)/mcu/eskin-mcu.elf --check python/eskin/deploy/cortex_m4_program.json
	for p in eskin-mcu eskin-mcu-deep eskin-mcu-overrun; do \
	  $(PY) tools/mcu_stack.py $(BUILD_MCU)/mcu/$$p.elf --write > /dev/null || exit 1; done
	set -o pipefail; mcu/run.sh $(BUILD_MCU)/mcu/eskin-mcu.elf | tee $(BUILD_MCU)/mcu.log
	@tail -n 1 $(BUILD_MCU)/mcu.log | grep -q '^MCU: .* parity=ok .* stack=[0-9]*/[0-9]*$$' || { echo "make mcu: no 'MCU: ... parity=ok ... stack=' line"; exit 1; }
	@for c in deep:'eskin-mcu: stack: a decision needs' overrun:'eskin-mcu: stack overflow'; do \
	  p=eskin-mcu-$${c%%:*}; status=0; \
	  mcu/run.sh $(BUILD_MCU)/mcu/$$p.elf > $(BUILD_MCU)/$$p.log 2>&1 || status=$$?; \
	  tail -n 1 $(BUILD_MCU)/$$p.log; \
	  if [ $$status -ne 5 ] || ! grep -q "^$${c#*:}" $(BUILD_MCU)/$$p.log; then \
	    echo "make mcu: $$p should have ended with exit status 5 and '$${c#*:}' (status $$status)"; exit 1; fi; \
	done; echo "MCU stack: a caller leaving less than a decision needs is refused at construction; without that rule the guard stops the overrun (exit status 5)"
	@if [ -d $(MCU_CASE)/nofit ]; then \
	  $(CMAKE) -S . -B $(BUILD_MCU)-nofit -G Ninja -DCMAKE_TOOLCHAIN_FILE=cmake/arm-none-eabi.cmake \
	    -DESKIN_DEVICE=ON -DCMAKE_BUILD_TYPE=Release \
	    -DESKIN_MCU_MODEL_HEADER=$(CURDIR)/$(MCU_CASE)/nofit/mcu_case.h >/dev/null && \
	  $(CMAKE) --build $(BUILD_MCU)-nofit >/dev/null && \
	  { status=0; mcu/run.sh $(BUILD_MCU)-nofit/mcu/eskin-mcu.elf > $(BUILD_MCU)/mcu-nofit.log 2>&1 || status=$$?; \
	    cat $(BUILD_MCU)/mcu-nofit.log; \
	    if [ $$status -eq 4 ] && grep -q '^eskin-mcu: out of memory' $(BUILD_MCU)/mcu-nofit.log; then \
	      echo "MCU heap bound: a model that does not fit is refused at construction (exit status 4)"; \
	    else echo "make mcu: the model that does not fit was not refused (exit status $$status)"; exit 1; fi; }; \
	fi
	@tail -n 1 $(BUILD_MCU)/mcu.log

# The controller firmware on the wire (docs/mcu.md, "The controller on the wire"): the device
# build's eskin-fw (eskin::Controller on the board's UART, samples from a timer interrupt) runs
# on QEMU's mps2-an386 under -icount shift=3 (the board's clock counts instructions, so whether
# the firmware keeps up does not depend on the host's load) with the model of `make mcu`'s case in its flash slot and 12
# held-out recordings of its campaign (4 per class); the host's unmodified `eskin listen
# PTY --model M --replay R` receives the stream, and the run ends with the line
# "MCU-LINK: frames=... samples=... lost=0 crc_errors=0 decisions=n decisions_dropped=0 agree=n/n".
# Any model: `make mcu-link MODEL=m.eskin CAMPAIGN=held.h5` puts a user's model in the flash slot
# and 4 recordings of each of its classes from the held-out campaign (each cut to the touch
# window the model's detector finds) on the board's ADC.
# MCU_PY_DEP= (empty) runs it with the package from python/ (PYTHONPATH) instead of installing it.
MCU_LINK := $(BUILD_MCU)/link
MCU_PY_DEP ?= install
mcu-link: mcu-deps $(MCU_PY_DEP)
	@if [ -n "$(MODEL)$(CAMPAIGN)" ] && { [ -z "$(MODEL)" ] || [ -z "$(CAMPAIGN)" ]; }; then \
	  echo "make mcu-link: MODEL=m.eskin and CAMPAIGN=held.h5 go together"; exit 2; fi
	@if [ -n "$(MODEL)" ]; then rm -rf $(MCU_CASE) && \
	  PATH="$(CURDIR)/$(VENV)/bin:$$PATH" $(PY) tools/mcu_case.py $(MCU_CASE) $(MCU_CASE_ARGS); \
	else test -f $(MCU_CASE)/model.eskin -a -f $(MCU_CASE)/campaign.h5 || \
	  PATH="$(CURDIR)/$(VENV)/bin:$$PATH" $(PY) tools/mcu_case.py $(MCU_CASE); fi
	$(CMAKE) -S . -B $(BUILD_MCU) -G Ninja -DCMAKE_TOOLCHAIN_FILE=cmake/arm-none-eabi.cmake \
	  -DESKIN_DEVICE=ON -DCMAKE_BUILD_TYPE=Release \
	  -DESKIN_MCU_MODEL_HEADER=$(CURDIR)/$(MCU_CASE)/mcu_case.h >/dev/null
	$(CMAKE) --build $(BUILD_MCU) --target eskin-fw
	$(PY) tools/mcu_elf_check.py $(BUILD_MCU)/mcu/eskin-fw.elf
	@mkdir -p $(MCU_LINK)
	$(PY) tools/mcu_link.py replay $(MCU_CASE) $(MCU_LINK)/stream.eskr \
	  $(if $(MODEL),--campaign $(abspath $(CAMPAIGN)))
	set -o pipefail; PATH="$(CURDIR)/$(VENV)/bin:$$PATH" $(PY) tools/mcu_link.py run \
	  --elf $(BUILD_MCU)/mcu/eskin-fw.elf --model $(MCU_CASE)/model.eskin \
	  --replay $(MCU_LINK)/stream.eskr --out $(MCU_LINK) | tee $(MCU_LINK)/mcu-link.log

# The demo needs the package and the two tools the editable install puts into $(VENV)/bin; not the
# GoogleTest suites, nor clang.
demo: install
	$(call step,eskin demo --out demo_out)
	PATH="$(CURDIR)/$(VENV)/bin:$$PATH" $(PY) -m eskin demo --out demo_out

# A whole skin (docs/skin.md): the 16 patches of docs/examples/forearm_skin.toml, each with its
# own simulated controller (`eskin fw-sim --skin`: one eskin-fw-sim per patch, on its own
# pseudo-terminal, classifying with the model on board), all read at once by one `eskin listen
# --skin` (a thread per link), which records every patch into one campaign (the patch field).
# The model is trained first on a small simulated campaign (eskin simulate, eskin train
# --quick); the skin plays SKIN_GESTURES gestures of SKIN_EPISODE seconds (slides across
# patch borders and touches on one patch) as fast as the host reads (--speed 0: nothing is
# lost). It ends with the line
# "SKIN-DEMO: patches=16 frames=N lost=0 crc_errors=0 decisions=N agree=N/N" (agree: the host's
# decision equals the controller's: same touch window, label and don't-know), or fails.
# SKIN_PY_DEP= (empty) runs it with the package from python/ (PYTHONPATH) instead of installing.
SKIN_DEMO := build/skin-demo
SKIN ?= docs/examples/forearm_skin.toml
SKIN_GESTURES ?= 8
SKIN_EPISODE ?= 1.5
SKIN_PY_DEP ?= install
ESKIN_CMD = PATH="$(CURDIR)/$(VENV)/bin:$$PATH" $(PY) -m eskin
skin-demo: $(SKIN_PY_DEP)
	$(call step,a skin of many patches: the model (eskin simulate$(,) eskin train --quick))
	@rm -rf $(SKIN_DEMO) && mkdir -p $(SKIN_DEMO)
	$(ESKIN_CMD) simulate -o $(SKIN_DEMO)/train.h5 --participants 6 --duration 2 --quiet
	$(ESKIN_CMD) train $(SKIN_DEMO)/train.h5 -o $(SKIN_DEMO)/touch.eskin --quick --no-progress \
	  > $(SKIN_DEMO)/train.log || { tail -20 $(SKIN_DEMO)/train.log; exit 1; }
	$(call step,the simulated skin: one replay per patch (eskin simulate --skin))
	$(ESKIN_CMD) simulate --skin $(SKIN) -o $(SKIN_DEMO)/sim --gestures $(SKIN_GESTURES) \
	  --episode $(SKIN_EPISODE)
	$(call step,one controller per patch (eskin fw-sim --skin)$(,) one host (eskin listen --skin))
	@$(ESKIN_CMD) fw-sim --skin $(SKIN) $(SKIN_DEMO)/sim --model $(SKIN_DEMO)/touch.eskin \
	  --speed 0 > $(SKIN_DEMO)/fw-sim.log 2>&1 & fw=$$!; \
	status=0; $(ESKIN_CMD) listen --skin $(SKIN) --sim $(SKIN_DEMO)/sim \
	  --model $(SKIN_DEMO)/touch.eskin --until-eof --duration 600 --wait-ports 60 \
	  --record $(SKIN_DEMO)/live.h5 > $(SKIN_DEMO)/listen.log 2>&1 || status=$$?; \
	wait $$fw || status=1; \
	grep -v '^patch .* \(decision\|recorded\) ' $(SKIN_DEMO)/listen.log; \
	grep '^ready:\|exit=' $(SKIN_DEMO)/fw-sim.log; \
	line=$$(tail -n 1 $(SKIN_DEMO)/listen.log); \
	received=$$(sed -n 's/^patch .* frames=[0-9]* samples=\([0-9]*\) .*/\1/p' $(SKIN_DEMO)/listen.log \
	  | awk '{n += $$1} END {print n + 0}'); \
	sent=$$(sed -n 's/^patch .* samples_sent=\([0-9]*\) .*/\1/p' $(SKIN_DEMO)/fw-sim.log \
	  | awk '{n += $$1} END {print n + 0}'); \
	echo "samples sent by the controllers: $$sent, received by the host: $$received"; \
	agree=$$(echo "$$line" | sed -n 's/.* decisions=\([0-9]*\) agree=\([0-9]*\)\/\([0-9]*\)$$/\1 \2 \3/p'); \
	set -- $$agree; \
	if [ $$status -ne 0 ] || ! echo "$$line" | grep -q '^skin: patches=[0-9]* .* lost=0 crc_errors=0 ' \
	  || [ -z "$$agree" ] || [ "$$1" -eq 0 ] || [ "$$2" != "$$3" ] || [ "$$1" != "$$3" ] \
	  || [ "$$sent" -eq 0 ] || [ "$$sent" != "$$received" ]; then \
	  echo "make skin-demo: failed (exit status $$status; last line: $$line)"; exit 1; fi; \
	echo "SKIN-DEMO: $${line#skin: }"

bench: install cpp
	for b in benchmarks/bench_*.py; do echo "== $$b"; ESKIN_BIN_DIR="$(CURDIR)/$(BUILD_CPP)" $(PY) $$b || exit 1; done

# Fast inner loop for developers: one CMake build with tests, tools and the module put in place
# next to python/eskin (no pip involved). Run the Python tests with `make devtest`.
dev: test-deps venv
	$(CMAKE) -S . -B $(BUILD_DEV) -G Ninja -DCMAKE_BUILD_TYPE=Release -DESKIN_BUILD_TESTS=ON \
	  -DESKIN_BUILD_PYTHON=ON -DESKIN_PYTHON_INPLACE=ON -DPython_EXECUTABLE=$(abspath $(PY)) \
	  -Dpybind11_DIR=$$($(PY) -m pybind11 --cmakedir) >/dev/null
	$(CMAKE) --build $(BUILD_DEV) -j $(JOBS)

devtest: dev venv-test mcu-deps
	cd $(BUILD_DEV) && ctest --output-on-failure -j $(JOBS)
	PYTHONPATH=python ESKIN_BIN_DIR="$(CURDIR)/$(BUILD_DEV)" $(PY) -m pytest -q tests/python

# Mutation testing of the modules that guard data and results (docs/testing.md; not part of
# `make test`): cosmic-ray for the Python modules, tools/mutation.py's own mutator for the C++
# ones. It prints its seed first ("MUTATION: seed=N": a fresh one each run, MUTATION_SEED=N runs
# the same sample again), then one line per module, "MUTATION: module=... mutants=N killed=K
# score=... ci95=[lo, hi] ...". MUTATION_SAMPLE mutants of each module run (a random sample;
# empty or `all`: every mutant); MUTATION_ONLY=path,path runs only those modules.
# `make mutation-diff` (BASE=rev, default the merge-base with main, or HEAD~1 on main): only the
# mutants on the lines the change touches, committed or not (all of them unless MUTATION_SAMPLE
# is given), as a check before handing a change over.
MUTATION_SAMPLE ?= 20
MUTATION_SEED ?=
MUTATION_ONLY ?=
BASE ?=
MUTATION_ARGS = $(if $(MUTATION_SEED),--seed $(MUTATION_SEED)) $(if $(MUTATION_ONLY),--only $(MUTATION_ONLY))
mutation-deps: dev venv-test
	$(PIP) install -q $$($(PY) -c "import tomllib;print(' '.join(tomllib.load(open('pyproject.toml','rb'))['project']['optional-dependencies']['mutation']))")

mutation: mutation-deps
	ESKIN_BIN_DIR="$(CURDIR)/$(BUILD_DEV)" $(PY) tools/mutation.py --sample "$(or $(MUTATION_SAMPLE),all)" $(MUTATION_ARGS)

mutation-diff: mutation-deps
	ESKIN_BIN_DIR="$(CURDIR)/$(BUILD_DEV)" $(PY) tools/mutation.py --diff $(BASE) --sample "$(if $(filter command line environment,$(origin MUTATION_SAMPLE)),$(or $(MUTATION_SAMPLE),all),all)" $(MUTATION_ARGS)

clean:
	rm -rf build python/eskin/_core*.so

# Regenerate the type stub of the compiled module (python/eskin/_core.pyi) from a dev build.
stubs: dev
	$(PIP) install -q pybind11-stubgen
	PYTHONPATH=python $(VENV)/bin/pybind11-stubgen eskin._core -o build/stubs
	$(PY) tools/fix_stub.py build/stubs/eskin/_core/__init__.pyi python/eskin/_core.pyi
