"""Start-up of the command line: building the parser (every ``reflexarm`` call, ``--version`` included)
imports no module that only a command needs; the commands import them when they run."""

from __future__ import annotations

import subprocess
import sys

import pytest

import reflexarm.tuning

#: Modules a command may need but registering its options must not import: SciPy (the threshold study's
#: Poisson check, the identification), the identification package (numba kernels), the study itself and
#: the plotting/table stacks.
HEAVY_MODULES = ("scipy", "reflexarm.ident", "reflexarm.tuning.study", "numba", "matplotlib", "pandas")


def _modules_after(code: str) -> set[str]:
    script = f"import sys\n{code}\nprint('\\n'.join(sys.modules))"
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    return set(res.stdout.split())


def test_building_the_parser_imports_no_heavy_module():
    loaded = _modules_after("import reflexarm.cli as c\nc.build_parser()")
    assert "reflexarm._cli.thresholds" in loaded and "reflexarm._cli.log_options" in loaded  # registered
    assert sorted(m for m in HEAVY_MODULES if m in loaded) == []


def test_a_command_still_finds_what_it_imports_on_first_use():
    loaded = _modules_after(
        "import contextlib, io, reflexarm.cli as c\n"
        "with contextlib.suppress(SystemExit), contextlib.redirect_stdout(io.StringIO()):\n"
        "    c.main(['tune-thresholds', '--help'])"
    )
    assert "reflexarm._cli.thresholds" in loaded
    assert "reflexarm.tuning.study" not in loaded  # --help is registration only
    loaded = _modules_after("from reflexarm.tuning import tune_thresholds")
    assert {"reflexarm.tuning.study", "scipy.stats"} <= loaded


def test_time_unit_choices_are_the_log_readers_units():
    from reflexarm._cli.log_options import TIME_UNIT_CHOICES
    from reflexarm.logs import TIME_UNITS

    assert TIME_UNIT_CHOICES == tuple(TIME_UNITS)


def test_the_tuning_package_exports_every_name_on_first_use():
    for name in reflexarm.tuning.__all__:
        assert getattr(reflexarm.tuning, name) is not None, name
    assert set(reflexarm.tuning.__all__) <= set(dir(reflexarm.tuning))
    with pytest.raises(AttributeError, match="module 'reflexarm.tuning' has no attribute 'tune_treshold'"):
        _ = reflexarm.tuning.tune_treshold  # type: ignore[attr-defined]
