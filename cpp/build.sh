#!/usr/bin/env bash
# For C++ developers: builds the reflexarm C++ library, its C++ tests and the C++ example into cpp/build/
# with the project's .venv (pin/libpinocchio, mujoco, cmeel-eigen wheels: run `make install` first), runs
# the C++ tests (ctest) and installs the library + CMake package config into cpp/build/install.
# The Python module reflexarm._core is NOT built here: `make install` builds it (scikit-build-core, into
# build/) and installs it into .venv; that is its only copy.
#
#   cpp/build.sh            configure + build + ctest + install tree + example
#   JOBS=1 cpp/build.sh     fewer parallel compiles (each Pinocchio TU needs ~0.6 GB)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(dirname "$here")"
py="${PYTHON:-$root/.venv/bin/python}"
build="$here/build"
jobs="${JOBS:-2}"

command -v cmake >/dev/null || { echo "cpp/build.sh: cmake not found (apt-get install cmake)" >&2; exit 1; }
command -v "${CXX:-g++}" >/dev/null || { echo "cpp/build.sh: no C++ compiler (apt-get install g++)" >&2; exit 1; }
"$py" -c "import cmeel, mujoco" 2>/dev/null || {
  echo "cpp/build.sh: the build requirements are missing in $py: run \`make install\` first" >&2
  exit 1
}
cmeel_prefix="$("$py" -m cmeel cmake 2>/dev/null)"
mujoco_dir="$("$py" -c 'import importlib.util, pathlib; print(pathlib.Path(importlib.util.find_spec("mujoco").origin).parent)')"
generator=()
command -v ninja >/dev/null && generator=(-G Ninja)

[ -f "$build/CMakeCache.txt" ] && generator=() # keep the generator of an existing build folder
cmake -S "$here" -B "$build" "${generator[@]}" -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_PREFIX_PATH="$cmeel_prefix" \
  -DREFLEXARM_BUILD_PYTHON=OFF -DREFLEXARM_BUILD_TESTS=ON \
  -DCMAKE_INSTALL_PREFIX="$build/install" >/dev/null
cmake --build "$build" -j "$jobs"
ctest --test-dir "$build" --output-on-failure
cmake --install "$build" >/dev/null

# the C++ example, built the way another project would: find_package(reflexarm) from the install tree
if [ -f "$root/examples/cpp/CMakeLists.txt" ]; then
  if [ ! -f "$build/example/CMakeCache.txt" ]; then
    cmake -S "$root/examples/cpp" -B "$build/example" "${generator[@]}" -DCMAKE_BUILD_TYPE=Release \
      -DCMAKE_PREFIX_PATH="$build/install;$cmeel_prefix" -DMUJOCO_DIR="$mujoco_dir"
  fi
  cmake --build "$build/example" -j "$jobs"
fi

rm -f "$build"/_core*.so # a module built here by an older cpp/build.sh (the module now comes from make install)
echo "cpp/build.sh: C++ tests passed; install tree in cpp/build/install, example in cpp/build/example/realtime_loop"
