import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from reflexarm.robots import load_robot  # noqa: E402


@pytest.fixture(scope="session")
def atlas():
    return load_robot("atlas_v5_left_arm")


@pytest.fixture(scope="session")
def panda_contact():
    """(robot, controller geometry, contact): a seeded contact on a distal Panda link (where point and force are
    determined), strong enough to detect, whose own joint carries more than the isolation's significance
    (0.25 x 11 Nm: a contact whose distal joints carry less is isolated to a more proximal link, "link or later", by
    design). Used by the oracle's isolation tests and tests/test_retract_from_residual.py."""
    import warnings

    import numpy as np

    from reflexarm.control.collision.classify import controller_geometry
    from reflexarm.experiments.isolation_study import draw_contacts
    from reflexarm.robots import link_collision_geometry

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        robot = load_robot("panda")
    truth = link_collision_geometry(robot, spacing=0.01, seed=3)
    contact = next(c for c in draw_contacts(robot, truth, 1000, seed=1) if c.link >= 4 and np.abs(c.torque).max() > 25
                   and abs(c.torque[c.link]) > 3.5)  # fmt: skip
    return robot, controller_geometry(robot), contact


SHARED = Path(__file__).resolve().parents[1].parent / "shared"
