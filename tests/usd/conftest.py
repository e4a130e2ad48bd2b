"""Fixtures for the USD reader tests.

usd_schemas is imported first so the illum schema plugin is registered before any test builds a
stage (the schema registry is initialised by the first stage and never re-reads plugins).
"""

import usd_schemas  # noqa: F401  (isort: skip)

import pytest
from pxr import Usd

from .helpers import new_stage


@pytest.fixture
def stage() -> Usd.Stage:
    """An in-memory Y-up stage with a camera at /Cam."""
    return new_stage()
