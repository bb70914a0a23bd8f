"""selfsense.sensing: the self-sensing estimator (thesis eqs. 52-55; paper eqs. 16-23)."""
from selfsense.sensing.estimator import (  # noqa: F401
    CalibrationError,
    SelfSensingEstimator,
    SensingConfig,
    h_target,
)
