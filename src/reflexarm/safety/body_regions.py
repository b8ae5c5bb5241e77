"""The ISO/TS 15066 body model: permissible forces, effective spring constants and effective masses of the
human body regions (ISO/TS 15066:2016 Annex A, now ISO 10218-2:2025 Annex A).

Sources, per column:

* ``quasi_static_force`` F_QS [N]: Table A.2 ("biomechanical limits"), column "maximum permissible force,
  quasi-static contact" of the body region (the region's value, not the per-area pressure values).
* ``transient_force`` F_T [N]: Table A.2 gives a *multiplier* of the quasi-static value for transient contact,
  2 for every region of the trunk, the arms and the legs, and for the neck. For the **skull/forehead and the
  face** the table gives no transient value (the multiplier column reads "not applicable": transient contact
  with the head is not among the permissible contacts). Where a number is needed for those two regions (a
  permissible speed), this table uses F_QS as a stand-in and marks it ``transient_given=False``: a choice of
  this package, conservative, not a value of the standard.
* ``spring_constant`` k [N/mm] and ``human_mass`` m_H [kg]: Table A.3 ("effective spring constant" and
  "effective mass" of the body model used by the transient-contact energy transfer of A.3).

The values were taken from the table as reproduced in public safety calculators and papers (the standard
itself is not public); the notes of this project (collision-pipeline anchors) list the same numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

from reflexarm.errors import ConfigError

__all__ = ["BODY_REGIONS", "BodyRegion", "body_region", "region_names"]

#: Where each value comes from.
TABLE_A2 = "ISO/TS 15066:2016 Table A.2"
TABLE_A3 = "ISO/TS 15066:2016 Table A.3"
#: The transient multiplier of Table A.2 for the regions that have one [-].
TRANSIENT_MULTIPLIER = 2.0


@dataclass(frozen=True)
class BodyRegion:
    """One body region of ISO/TS 15066 Annex A.

    Attributes:
        name: the region's key (``"chest"``, ``"hand"``, ...).
        title: the region as the standard names it.
        quasi_static_force: F_QS, permissible quasi-static (clamping) contact force [N] (Table A.2, given).
        transient_force: F_T, permissible transient contact force [N]; 2 x F_QS where Table A.2 gives the
            multiplier 2 (``transient_given`` True); F_QS as a conservative stand-in where the table gives
            none (skull/forehead, face; ``transient_given`` False).
        transient_given: whether F_T is the standard's value (True) or this package's stand-in (False).
        spring_constant: k, effective spring constant of the region [N/mm] (Table A.3, given).
        human_mass: m_H, effective mass of the region [kg] (Table A.3, given).
        sources: per attribute the table it comes from and "given" or "derived".
        note: what the standard says beyond the numbers.
    """

    name: str
    title: str
    quasi_static_force: float
    transient_force: float
    transient_given: bool
    spring_constant: float
    human_mass: float
    sources: tuple[tuple[str, str], ...]
    note: str = ""

    @property
    def spring_constant_si(self) -> float:
        """k in SI units [N/m]."""
        return self.spring_constant * 1e3

    def describe(self) -> dict[str, object]:
        """JSON-ready values with their units in the keys."""
        return {
            "region": self.name,
            "title": self.title,
            "F_QS_N": self.quasi_static_force,
            "F_T_N": self.transient_force,
            "F_T_given": self.transient_given,
            "k_N_per_mm": self.spring_constant,
            "m_H_kg": self.human_mass,
            "sources": dict(self.sources),
            "note": self.note,
        }


def _region(name: str, title: str, f_qs: float, k: float, m_h: float, *, transient: bool = True) -> BodyRegion:
    f_t = TRANSIENT_MULTIPLIER * f_qs if transient else f_qs
    sources = (
        ("quasi_static_force", f"{TABLE_A2}, given"),
        (
            "transient_force",
            f"{TABLE_A2}, derived: F_QS x multiplier {TRANSIENT_MULTIPLIER:g} given in the table"
            if transient
            else f"{TABLE_A2} gives none (transient multiplier not applicable); F_QS used as a stand-in, derived",
        ),
        ("spring_constant", f"{TABLE_A3}, given"),
        ("human_mass", f"{TABLE_A3}, given"),
    )
    note = "" if transient else "no permissible transient contact in Table A.2: keep the robot away from the head"
    return BodyRegion(name, title, f_qs, f_t, transient, k, m_h, sources, note)


#: The twelve regions of Annex A, by key.
BODY_REGIONS: dict[str, BodyRegion] = {
    r.name: r
    for r in (
        _region("skull", "skull and forehead", 130.0, 150.0, 4.4, transient=False),
        _region("face", "face", 65.0, 75.0, 4.4, transient=False),
        _region("neck", "neck", 150.0, 50.0, 1.2),
        _region("back", "back and shoulders", 210.0, 35.0, 40.0),
        _region("chest", "chest", 140.0, 25.0, 40.0),
        _region("abdomen", "abdomen", 110.0, 10.0, 40.0),
        _region("pelvis", "pelvis", 180.0, 25.0, 40.0),
        _region("upper_arm", "upper arms and elbow joints", 150.0, 30.0, 3.0),
        _region("lower_arm", "lower arms and wrist joints", 160.0, 40.0, 2.0),
        _region("hand", "hands and fingers", 140.0, 75.0, 0.6),
        _region("thigh", "thighs and knees", 220.0, 50.0, 75.0),
        _region("lower_leg", "lower legs", 130.0, 60.0, 75.0),
    )
}


def region_names() -> tuple[str, ...]:
    """The keys of :data:`BODY_REGIONS`, in the standard's order (head to feet)."""
    return tuple(BODY_REGIONS)


def body_region(region: str | BodyRegion) -> BodyRegion:
    """The region ``region`` (a key of :data:`BODY_REGIONS` or a :class:`BodyRegion`, returned as is).

    Raises:
        ConfigError: an unknown key, naming the valid ones.
    """
    if isinstance(region, BodyRegion):
        return region
    key = str(region).strip().lower().replace("-", "_").replace(" ", "_")
    if key not in BODY_REGIONS:
        raise ConfigError(f"unknown body region {region!r}; regions are: {', '.join(BODY_REGIONS)}")
    return BODY_REGIONS[key]
