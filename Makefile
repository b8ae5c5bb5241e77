# reflexarm: every target sets itself up (virtual environment + pinned install) on a fresh machine.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
DEPS_STAMP := $(VENV)/.build-deps-stamp
OUT ?= results

# The C++ core needs cmake (>= 3.18) and a C++17 compiler ($$CXX, c++, g++ or clang++) on the machine.
CHECK_TOOLCHAIN = command -v cmake >/dev/null 2>&1 || { \
	  echo "error: cmake not found: reflexarm's C++ core (cpp/) needs cmake >= 3.18 and a C++17 compiler" >&2; \
	  echo "       install them (Debian/Ubuntu: sudo apt-get install cmake g++) and run make again" >&2; exit 1; }; \
	command -v "$${CXX:-c++}" >/dev/null 2>&1 || command -v g++ >/dev/null 2>&1 || command -v clang++ >/dev/null 2>&1 || { \
	  echo "error: no C++ compiler found (\$$CXX, c++, g++, clang++): reflexarm's C++ core (cpp/) needs a C++17 compiler" >&2; \
	  echo "       install one (Debian/Ubuntu: sudo apt-get install g++) and run make again" >&2; exit 1; }

.PHONY: install demo test test-fast bench lint clean sanitize

# The C++ sources of the module reflexarm._core (cpp/tests and the C++ example are not part of it): a change
# re-runs the install, which recompiles what changed in build/ (scikit-build-core, no build isolation).
CORE_SOURCES := cpp/CMakeLists.txt $(wildcard cpp/cmake/* cpp/include/reflexarm/*.hpp cpp/src/*.cpp cpp/src/*.hpp cpp/bindings/*.cpp cpp/bindings/*.hpp)

# 1) the virtual environment and the build requirements ([build-system].requires of pyproject.toml, pinned to
#    the runtime wheels); 2) the package itself, editable, with the C++ core compiled into build/.
$(DEPS_STAMP): pyproject.toml
	@$(CHECK_TOOLCHAIN)
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet pip==26.3 # pinned, so that a new pip cannot change how the sdists below are built
	$(BIN)/python -c 'import tomllib; print("\n".join(tomllib.load(open("pyproject.toml", "rb"))["build-system"]["requires"]))' > $(VENV)/build-requirements.txt
	$(BIN)/python -m pip install --quiet -r $(VENV)/build-requirements.txt
	touch $(DEPS_STAMP)

# The editable install maps each module to its file when it is installed: a module added, moved or renamed
# (a folder's time stamp changes) re-runs it too (about 4 s when the C++ core is unchanged).
PACKAGE_DIRS := $(shell find src/reflexarm -type d -not -name __pycache__ 2>/dev/null)

$(STAMP): $(DEPS_STAMP) $(CORE_SOURCES) $(PACKAGE_DIRS)
	@$(CHECK_TOOLCHAIN)
	rm -f src/reflexarm/_core*.so # a module copied there by an old cpp/build.sh: the installed one is the only one
	$(BIN)/python -m pip install --quiet --no-build-isolation -e ".[dev,video,ros]"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	MPLBACKEND=Agg $(BIN)/reflexarm demo --out $(OUT)/demo

test: $(STAMP)
	MPLBACKEND=Agg $(BIN)/python -m pytest -n 2 --dist loadfile -q

test-fast: $(STAMP)
	MPLBACKEND=Agg $(BIN)/python -m pytest -n 2 --dist loadfile -q -m "not slow"

bench: $(STAMP)
	MPLBACKEND=Agg $(BIN)/python bench/run_all.py

# The C++ library and its tests (cpp/tests) under AddressSanitizer + UBSan (-DREFLEXARM_SANITIZE=ON) in
# cpp/build-sanitize: configure, build (SAN_JOBS=1 on a small machine), run both tests; any report fails the run
# (UBSan does not recover; ASan aborts on the first error). cpp/sanitize/ubsan.supp: empty (its history).
SAN_JOBS ?= 2
sanitize:
	@$(CHECK_TOOLCHAIN)
	@$(BIN)/python -c "import cmeel" 2>/dev/null || { echo "error: make sanitize needs the build requirements in $(VENV): run make install first" >&2; exit 1; }
	cmake -S cpp -B cpp/build-sanitize -DCMAKE_BUILD_TYPE=RelWithDebInfo \
	  -DCMAKE_PREFIX_PATH="$$($(BIN)/python -m cmeel cmake 2>/dev/null)" \
	  -DREFLEXARM_BUILD_PYTHON=OFF -DREFLEXARM_BUILD_TESTS=ON -DREFLEXARM_SANITIZE=ON >/dev/null
	cmake --build cpp/build-sanitize -j $(SAN_JOBS) --target test_controller test_isolation test_modal_damping
	ASAN_OPTIONS=detect_leaks=1:strict_string_checks=1:detect_stack_use_after_return=1 \
	UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1:suppressions=$(CURDIR)/cpp/sanitize/ubsan.supp \
	  ctest --test-dir cpp/build-sanitize --output-on-failure

lint: $(STAMP)
	$(BIN)/ruff check src tests bench examples
	$(BIN)/mypy

clean:
	rm -rf $(VENV) $(OUT) build .pytest_cache .mypy_cache .ruff_cache
