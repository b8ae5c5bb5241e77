"""Learning the model (Sec. II-D): logs in, single-joint friction, base parameters, Fourier excitation,
weighted least squares (combined and sequential), validation, and the identified model written back.

Never imports :mod:`reflexarm.control`; the experiments that run the plant with the controller live in
:mod:`reflexarm.experiments.identification`.
"""

from reflexarm.ident.base_parameters import BaseParameters, IllConditionedWarning, compute_base_parameters
from reflexarm.ident.estimation import (
    METHODS,
    DynamicsIdentification,
    FrictionParameters,
    TorqueValidation,
    identify_dynamics,
    validate_model,
)
from reflexarm.ident.logs import DEFAULT_CUTOFF_HZ, LogRepairWarning, RobotLog, load_log, preprocess_log, save_log
from reflexarm.ident.regressor import BatchRegressor, compute_friction_regressor

__all__ = [
    "DEFAULT_CUTOFF_HZ",
    "METHODS",
    "BaseParameters",
    "BatchRegressor",
    "DynamicsIdentification",
    "FrictionParameters",
    "IllConditionedWarning",
    "LogRepairWarning",
    "RobotLog",
    "TorqueValidation",
    "compute_base_parameters",
    "compute_friction_regressor",
    "identify_dynamics",
    "load_log",
    "preprocess_log",
    "save_log",
    "validate_model",
]
