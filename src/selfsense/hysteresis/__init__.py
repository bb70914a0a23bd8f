"""selfsense.hysteresis: modified Prandtl-Ishlinskii operators (thesis 000_18d138f03f1777c3.txt sec. 4.2)."""
# the compiled kernels, for callers that compile them into their own loops (selfsense.sensing.streaming)
from ._kernels import creep_kernel, gamma_kernel  # noqa: F401
from .operators import creep_operator, log_creep_eigenvalues, play_operator, superposition_operator  # noqa: F401
from .pi import ModifiedPI, PIState, invert_superposition  # noqa: F401
from .identify import FitReport, IdentificationError, fit_modified_pi  # noqa: F401
