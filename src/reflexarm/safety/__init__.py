"""Human contact limits (ISO/TS 15066 power and force limiting): the body regions, the arm's effective mass,
permissible speeds and the check of a whole motion."""

from reflexarm.safety.body_regions import BODY_REGIONS, BodyRegion, body_region, region_names
from reflexarm.safety.effective_mass import (
    ContactPoint,
    contact_points,
    effective_mass,
    moving_mass,
    peak_transient_force,
    permissible_speed,
    permissible_speed_for_mass,
    point_jacobian,
    reduced_mass,
    standard_robot_mass,
)
from reflexarm.safety.trajectory_check import SpeedCheck, check_trajectory_speed

__all__ = [
    "BODY_REGIONS",
    "BodyRegion",
    "ContactPoint",
    "SpeedCheck",
    "body_region",
    "check_trajectory_speed",
    "contact_points",
    "effective_mass",
    "moving_mass",
    "peak_transient_force",
    "permissible_speed",
    "permissible_speed_for_mass",
    "point_jacobian",
    "reduced_mass",
    "region_names",
    "standard_robot_mass",
]
