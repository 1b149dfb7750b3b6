"""Fixtures shared by the tests. Shared code that is not a fixture lives in tests/helpers/ (imported as
``helpers.<module>``): a test module never imports from this file or from another test module."""

import pytest


@pytest.fixture
def quiet():
    """An ``echo`` for ``train`` that prints nothing."""
    return lambda s: None
