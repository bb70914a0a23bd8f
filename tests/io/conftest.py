"""Fixtures of the io tests; the dataset factory lives in io_factory.py (a unique module name, so that it cannot
collide with other test folders' conftest modules under pytest's prepend import mode)."""
from io_factory import dataset, pristine  # noqa: F401
