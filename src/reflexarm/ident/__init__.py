"""Learning the model (Sec. II-D): logs in, single-joint friction (or friction from ordinary motion), base
parameters, Fourier excitation, weighted least squares (combined and sequential) with the file's armature and
joint springs as known terms, validation, and what the user takes away: the identified model (model file, and
a copy of the robot file with the identified inertias and friction, :func:`write_identified_robot`) and the
excitation as a sampled trajectory (:func:`sample_excitation`, :func:`write_excitation_csv`); a payload at the
tool (:func:`identify_payload`, :func:`detect_payload_change`).

Never imports :mod:`reflexarm.control`; the experiments that run the plant with the controller live in
:mod:`reflexarm.experiments.identification`. Figures are in :mod:`reflexarm.ident.plots`.
"""

from reflexarm.ident.estimation.base_parameters import BaseParameters, IllConditionedWarning, compute_base_parameters
from reflexarm.ident.estimation.consistency import project_physically_consistent
from reflexarm.ident.estimation.identify import (
    METHODS,
    DynamicsIdentification,
    FrictionParameters,
    PhysicalConsistencyWarning,
    TorqueValidation,
    identify_dynamics,
    mass_matrix_margin,
    validate_model,
)
from reflexarm.ident.estimation.known_terms import KnownJointTerms
from reflexarm.ident.estimation.regressor import BatchRegressor, compute_friction_regressor
from reflexarm.ident.excitation.design import ExcitationDesign, FourierTrajectory, optimize_excitation
from reflexarm.ident.excitation.export import (
    ExcitationLimitError,
    ExcitationMarginWarning,
    SampledExcitation,
    sample_excitation,
    write_excitation_csv,
)
from reflexarm.ident.export.model_file import (
    load_identified_model,
    load_model_robot,
    read_identified_model,
    save_identified_model,
)
from reflexarm.ident.export.write_back import with_consistent_links, write_identified_robot
from reflexarm.ident.friction.from_motion import MotionFriction, identify_friction_from_motion
from reflexarm.ident.friction.joint_friction import (
    ConstantVelocityTrajectory,
    FrictionFit,
    FrictionPoint,
    fit_friction,
    friction_from_fits,
    friction_points,
    identify_joint_friction,
    plan_friction_experiment,
    segment_constant_velocity,
)
from reflexarm.ident.friction.parameters import (
    ImplausibleFrictionWarning,
    MissingFrictionError,
    check_friction_plausibility,
)
from reflexarm.ident.payload import Payload, PayloadChange, detect_payload_change, identify_payload, with_payload
from reflexarm.logs import DEFAULT_CUTOFF_HZ, LogRepairWarning, RobotLog, load_log, preprocess_log, save_log

__all__ = [
    "DEFAULT_CUTOFF_HZ",
    "METHODS",
    "BaseParameters",
    "BatchRegressor",
    "ConstantVelocityTrajectory",
    "DynamicsIdentification",
    "ExcitationDesign",
    "ExcitationLimitError",
    "ExcitationMarginWarning",
    "FourierTrajectory",
    "FrictionFit",
    "FrictionParameters",
    "FrictionPoint",
    "IllConditionedWarning",
    "ImplausibleFrictionWarning",
    "KnownJointTerms",
    "LogRepairWarning",
    "MissingFrictionError",
    "MotionFriction",
    "Payload",
    "PayloadChange",
    "PhysicalConsistencyWarning",
    "RobotLog",
    "SampledExcitation",
    "TorqueValidation",
    "check_friction_plausibility",
    "compute_base_parameters",
    "compute_friction_regressor",
    "detect_payload_change",
    "fit_friction",
    "friction_from_fits",
    "friction_points",
    "identify_dynamics",
    "identify_friction_from_motion",
    "identify_joint_friction",
    "identify_payload",
    "load_identified_model",
    "load_log",
    "load_model_robot",
    "mass_matrix_margin",
    "optimize_excitation",
    "plan_friction_experiment",
    "preprocess_log",
    "project_physically_consistent",
    "read_identified_model",
    "sample_excitation",
    "save_identified_model",
    "save_log",
    "segment_constant_velocity",
    "validate_model",
    "with_consistent_links",
    "with_payload",
    "write_excitation_csv",
    "write_identified_robot",
]
