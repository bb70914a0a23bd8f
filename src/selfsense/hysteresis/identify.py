class FitReport: pass
class IdentificationError(ValueError): pass
def fit_modified_pi(*a, **k): raise NotImplementedError
