"""The ISO/TS 15066 body table against the standard's published numbers, written here from Annex A (Table A.2:
quasi-static forces and the transient multiplier; Table A.3: spring constants and effective masses), not read
from the package."""

from __future__ import annotations

import dataclasses

import pytest

from reflexarm.errors import ConfigError
from reflexarm.safety import BODY_REGIONS, body_region, region_names

#: region: (F_QS [N] Table A.2, k [N/mm] Table A.3, m_H [kg] Table A.3)
PUBLISHED = {
    "skull": (130.0, 150.0, 4.4),
    "face": (65.0, 75.0, 4.4),
    "neck": (150.0, 50.0, 1.2),
    "back": (210.0, 35.0, 40.0),
    "chest": (140.0, 25.0, 40.0),
    "abdomen": (110.0, 10.0, 40.0),
    "pelvis": (180.0, 25.0, 40.0),
    "upper_arm": (150.0, 30.0, 3.0),
    "lower_arm": (160.0, 40.0, 2.0),
    "hand": (140.0, 75.0, 0.6),
    "thigh": (220.0, 50.0, 75.0),
    "lower_leg": (130.0, 60.0, 75.0),
}
#: Table A.2's transient multiplier column: 2 for the neck, trunk and limbs; "not applicable" for the head.
NO_TRANSIENT = {"skull", "face"}


def test_every_region_of_annex_a_and_no_other():
    assert set(region_names()) == set(PUBLISHED)


@pytest.mark.parametrize("name", sorted(PUBLISHED))
def test_values_are_the_published_ones(name):
    f_qs, k, m_h = PUBLISHED[name]
    r = body_region(name)
    assert (r.quasi_static_force, r.spring_constant, r.human_mass) == (f_qs, k, m_h)
    assert r.spring_constant_si == k * 1000.0  # N/mm -> N/m
    if name in NO_TRANSIENT:
        assert not r.transient_given
        assert r.transient_force == f_qs  # the package's stand-in, marked as not given
        assert "not applicable" in dict(r.sources)["transient_force"]
    else:
        assert r.transient_given
        assert r.transient_force == 2.0 * f_qs
    assert dict(r.sources)["spring_constant"].startswith("ISO/TS 15066:2016 Table A.3")
    assert dict(r.sources)["quasi_static_force"].startswith("ISO/TS 15066:2016 Table A.2")


def test_the_table_is_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        BODY_REGIONS["chest"].quasi_static_force = 500.0  # type: ignore[misc]


def test_an_unknown_region_names_the_choices():
    with pytest.raises(ConfigError, match=r"unknown body region 'belly'; regions are: skull, face, neck, .*hand"):
        body_region("belly")
    assert body_region("Upper-Arm").name == "upper_arm"
