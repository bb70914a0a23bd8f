"""selfsense.gap: the stage-wise sim-to-real gap diagnostic (docs/gap.md).

Modules:

* :mod:`~selfsense.gap.stages`: the stages (holds, electrical, mechanical, load), their nominal models and member
  libraries, and :func:`~selfsense.gap.stages.diagnose_stages`;
* :mod:`~selfsense.gap.counterfactual`: how far the gap shrinks, with the configured estimator recalibrated;
* :mod:`~selfsense.gap.pipeline`: the pipeline rule ``gap_diagnose`` and ``selfsense gap diagnose``;
* :mod:`~selfsense.gap.blind`, :mod:`~selfsense.gap.blindsim`: the blind check on the device families;
* :mod:`~selfsense.gap.protocol`: the excitation check and the protocol proposal;
* :mod:`~selfsense.gap.standin`: the load stage's fixed-form force estimate;
* :mod:`~selfsense.gap.stats`: exact Shapley values.
"""
