"""The package as a user installs it: a release wheel (abi3: one wheel for CPython >= 3.9),
stripped, its extension under 10 MB. scripts/test builds it and runs the whole suite in a
clean virtual environment with BEAD_WHEEL set to the wheel; elsewhere (a development
install) these checks do not apply and are skipped."""

import os
from pathlib import Path

import pytest

import bead

WHEEL = os.environ.get("BEAD_WHEEL")
pytestmark = pytest.mark.skipif(
    not WHEEL, reason="checks the wheel scripts/test builds (BEAD_WHEEL unset)")


def test_the_wheel_is_abi3_and_its_extension_small_and_installed_from_it():
    wheel = Path(WHEEL)
    assert wheel.name.startswith("bead-") and "-abi3-" in wheel.name, wheel.name
    extension = Path(bead._bead.__file__)
    assert extension.name.endswith(".abi3.so"), extension.name
    size = extension.stat().st_size
    assert size < 10_000_000, f"{extension}: {size} bytes"
    # The package imported is the installed one, not the sources.
    assert "site-packages" in str(extension)
