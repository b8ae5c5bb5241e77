#!/usr/bin/env bash
# Builds the reflexarm C++ core, its C++ tests, the nanobind module reflexarm._core and the C++ example
# into cpp/build/ with the project's .venv (pin/libpinocchio, mujoco, nanobind, cmeel-eigen wheels), runs
# the C++ tests, and copies the module next to the Python package (src/reflexarm/) for the editable install.
#
#   cpp/build.sh            configure (once) + build + ctest + copy the module
#   JOBS=1 cpp/build.sh     fewer parallel compiles (each Pinocchio TU needs ~0.6 GB)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(dirname "$here")"
py="${PYTHON:-$root/.venv/bin/python}"
build="$here/build"
jobs="${JOBS:-2}"

command -v cmake >/dev/null || { echo "cpp/build.sh: cmake not found (apt-get install cmake)" >&2; exit 1; }
command -v "${CXX:-g++}" >/dev/null || { echo "cpp/build.sh: no C++ compiler (apt-get install g++)" >&2; exit 1; }
for mod in nanobind cmeel; do
  "$py" -c "import $mod" 2>/dev/null || {
    echo "cpp/build.sh: Python package '$mod' missing in $py; install the build requirements:" >&2
    echo "  $py -m pip install nanobind==3.1.0 scikit-build-core==1.1.2 cmeel-eigen==3.4.1 cmeel-urdfdom-headers==3.0.0" >&2
    exit 1
  }
done
cmeel_prefix="$("$py" -m cmeel cmake 2>/dev/null)"
mujoco_dir="$("$py" -c 'import importlib.util, pathlib; print(pathlib.Path(importlib.util.find_spec("mujoco").origin).parent)')"
generator=()
command -v ninja >/dev/null && generator=(-G Ninja)

if [ ! -f "$build/CMakeCache.txt" ]; then
  cmake -S "$here" -B "$build" "${generator[@]}" -DCMAKE_BUILD_TYPE=Release \
    -DCMAKE_PREFIX_PATH="$cmeel_prefix" \
    -DPython_EXECUTABLE="$py" \
    -Dnanobind_DIR="$("$py" -m nanobind --cmake_dir)" \
    -DREFLEXARM_BUILD_PYTHON=ON -DREFLEXARM_BUILD_TESTS=ON \
    -DCMAKE_INSTALL_PREFIX="$build/install"
fi
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

module="$(ls "$build"/_core*.so)"
cp "$module" "$root/src/reflexarm/"
echo "cpp/build.sh: built $(basename "$module") -> src/reflexarm/"
