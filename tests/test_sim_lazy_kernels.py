"""The plant's numba kernels load on first use: importing reflexarm.sim and building a Plant (all a run in the
compiled loop needs) must not import numba (~110 MB of a `simulate free-motion` run's peak memory)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from reflexarm.sim import _kernel_layout, _kernels, _kernels_lazy


def test_a_plant_is_built_without_numba():
    code = (
        "import sys\n"
        "from reflexarm import load_robot\n"
        "from reflexarm.sim import Plant, JointTrajectory\n"
        "Plant(load_robot('panda'))\n"
        "JointTrajectory(__import__('numpy').zeros((2, 7)), __import__('numpy').ones(1))\n"
        "print('numba' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=300)
    assert out.stdout.strip().splitlines()[-1] == "False", out.stdout + out.stderr


def test_the_lazy_kernels_are_the_modules_own():
    assert _kernels_lazy.kernels.sum_squares is _kernels.sum_squares
    assert _kernels_lazy.kernels.sum_squares(np.array([3.0, 4.0])) == 25.0
    assert (_kernels.IDX_N, _kernels.IDX_HEADER) == (_kernel_layout.IDX_N, _kernel_layout.IDX_HEADER) == (0, 7)
