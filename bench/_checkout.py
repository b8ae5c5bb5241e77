"""Import reflexarm from a given checkout, for benches that time two checkouts against each other.

The editable install (``make install``) puts an import finder on ``sys.meta_path`` that maps ``reflexarm`` to
the checkout it was installed from, ahead of ``PYTHONPATH``. :func:`use_checkout` removes that finder, puts
``CHECKOUT/src`` first on ``sys.path`` and maps the compiled modules (``reflexarm._core``,
``reflexarm._closed_loop``) to the ones built in ``CHECKOUT/build/<wheel tag>/``, the folder where
scikit-build-core compiles them (``make install`` in that checkout, or :data:`BUILD_HINT`). Call it before
anything imports reflexarm.

    python bench/_checkout.py CHECKOUT MODULE [ARGS...]   # runs MODULE.serve() with reflexarm from CHECKOUT
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.util
import runpy
import sys
import sysconfig
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

COMPILED = ("_core", "_closed_loop")
BUILD_HINT = "{python} -m pip wheel --no-build-isolation --no-deps -w {checkout}/build/wheel {checkout}"


class CheckoutError(RuntimeError):
    """A checkout that cannot be imported as asked (no package, no build, or another reflexarm won)."""


class _CompiledModules(importlib.abc.MetaPathFinder):
    """Finds ``reflexarm._core`` and ``reflexarm._closed_loop`` at given files (and nothing else)."""

    def __init__(self, files: dict[str, Path]) -> None:
        self.files = files

    def find_spec(
        self, fullname: str, path: Sequence[str] | None = None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        file = self.files.get(fullname)
        return None if file is None else importlib.util.spec_from_file_location(fullname, file)


def compiled_modules(checkout: Path) -> dict[str, Path]:
    """The compiled modules built in ``checkout/build/*/`` for this interpreter ({} for a checkout without cpp/).

    Raises CheckoutError naming the build command when the checkout has C++ sources but no build of them.
    """
    if not (checkout / "cpp").is_dir():
        return {}
    suffix = sysconfig.get_config_var("EXT_SUFFIX")
    found: dict[str, Path] = {}
    for name in COMPILED:
        # build/<wheel tag>/ (scikit-build-core), or src/reflexarm/ (where early checkouts' cpp/build.sh put it)
        built = [
            *(checkout / "build").glob(f"*/{name}{suffix}"),
            *(checkout / "src" / "reflexarm").glob(f"{name}{suffix}"),
        ]
        files = sorted(built, key=lambda p: p.stat().st_mtime)
        if files:
            found[f"reflexarm.{name}"] = files[-1]  # the newest build folder's
    if "reflexarm._core" not in found:
        hint = BUILD_HINT.format(python=sys.executable, checkout=checkout)
        raise CheckoutError(
            f"no reflexarm._core{suffix} built in {checkout}/build/*/; expected the checkout's own build (the one "
            f"`make install` makes there); build it with:\n    {hint}"
        )
    return found


def stale_sources(checkout: Path, modules: dict[str, Path]) -> list[Path]:
    """Sources of ``reflexarm._core`` in ``checkout`` (as the Makefile lists them: cpp/CMakeLists.txt, cpp/cmake,
    cpp/include, cpp/src, cpp/bindings; the closed loop's files left out) newer than the built module."""
    core = modules.get("reflexarm._core")
    if core is None:
        return []
    built = core.stat().st_mtime
    cpp = checkout / "cpp"
    folders = ("cmake", "include", "src", "bindings")
    sources = [cpp / "CMakeLists.txt", *(p for d in folders for p in (cpp / d).rglob("*"))]
    return sorted(p for p in sources if p.is_file() and "closed_loop" not in p.name and p.stat().st_mtime > built)


def use_checkout(checkout: Path) -> dict[str, Path]:
    """Make ``import reflexarm`` load ``checkout/src`` and its compiled modules; returns those modules' files."""
    checkout = checkout.resolve()
    src = checkout / "src"
    if not (src / "reflexarm" / "__init__.py").is_file():
        raise CheckoutError(f"{checkout} is not a reflexarm checkout: {src}/reflexarm/__init__.py not found")
    if "reflexarm" in sys.modules:
        first = sys.modules["reflexarm"].__file__
        raise CheckoutError(f"reflexarm was imported before use_checkout({checkout}), from {first}")
    modules = compiled_modules(checkout)
    # the editable install's finder knows the modules of the checkout it was installed from
    sys.meta_path[:] = [f for f in sys.meta_path if "reflexarm" not in getattr(f, "known_source_files", {})]
    sys.meta_path.insert(0, _CompiledModules(modules))
    sys.path.insert(0, str(src))
    return modules


def loaded_files() -> tuple[Path, Path | None]:
    """The folder reflexarm was imported from and the file of its loaded core (None if not loaded)."""
    import reflexarm

    core = sys.modules.get("reflexarm._core")
    core_file = None if core is None else Path(core.__file__ or "").resolve()
    return Path(reflexarm.__file__ or "").resolve().parent, core_file


def check_loaded(checkout: Path, package: Path, core: Path | None) -> None:
    """CheckoutError unless the package and its core came from ``checkout``."""
    checkout = checkout.resolve()
    if not package.is_relative_to(checkout / "src"):
        raise CheckoutError(f"reflexarm was imported from {package}, not from the checkout {checkout}")
    if core is not None and not core.is_relative_to(checkout):
        raise CheckoutError(f"reflexarm._core was imported from {core}, not from a build of {checkout}")


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    use_checkout(Path(sys.argv[1]))
    sys.argv = [sys.argv[2], *sys.argv[3:]]
    runpy.run_module(sys.argv[0], run_name="__main__", alter_sys=True)
