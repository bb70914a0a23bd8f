"""selfsense.chain: the stage chain the signal passes (u_cmd -> V -> Q -> V_p -> tip / load), one module per link.

Each link's members are physical models that the estimator can carry and the gap diagnostic tests with the same
functions, so that what the diagnostic names is what the estimator can correct.
"""
from selfsense.chain.charge import HoldEvidence, find_holds, hold_evidence, leak_column  # noqa: F401
