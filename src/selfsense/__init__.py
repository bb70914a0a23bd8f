"""selfsense: force and displacement self-sensing for amplified piezoelectric actuators.

The science follows three seed documents, cited by file name (references in CITATION.cff):
``000_18d138f03f1777c3.txt`` (thesis), ``001_972cacfaa08ad91a.txt`` (on-site calibration paper) and
``002_7d89b7147aad52e4.txt`` (one-sided rate-independent hysteresis model).
"""

__version__ = "0.1.0"  # the single version source (pyproject.toml reads it; CHANGELOG.md)


def version() -> str:
    """Installed package version (``importlib.metadata``), falling back to ``__version__``."""
    try:
        from importlib.metadata import version as _v

        return _v("selfsense")
    except Exception:  # pragma: no cover - not installed as a distribution
        return __version__
