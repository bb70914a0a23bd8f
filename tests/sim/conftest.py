import pytest

FREE = dict(trial="t_free", role="calibration", tip="free", reference="displacement", signal="sine",
            duration=5.0, freq=0.5, levels=[[1.0, 0.0]])


@pytest.fixture
def free_trial():
    return dict(FREE)


@pytest.fixture
def blocked_trial():
    return dict(FREE, trial="t_blk", tip="blocked", reference="force")
