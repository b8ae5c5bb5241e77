import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from reflexarm.robots import load_robot  # noqa: E402


@pytest.fixture(scope="session")
def atlas():
    return load_robot("atlas_v5_left_arm")


SHARED = Path(__file__).resolve().parents[1].parent / "shared"
