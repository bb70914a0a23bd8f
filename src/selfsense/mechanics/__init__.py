"""selfsense.mechanics: two-port mechanism models and the combined piezo/tweezer statics.

Thesis 000_18d138f03f1777c3.txt eqs. (1)-(27), (44)-(59); paper 001_972cacfaa08ad91a.txt eqs. (13)-(23).
"""
from . import device, piezo, twoport  # noqa: F401
from .device import TweezerMechanics, default_tweezer_mechanics  # noqa: F401
from .twoport import TwoPort  # noqa: F401
