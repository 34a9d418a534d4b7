"""Missing reference data skips a test on a developer's machine and fails it in CI."""

from __future__ import annotations

import pytest


def test_missing_reference_data_skips_locally_and_fails_in_ci(missing_data, monkeypatch):
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="CI=true"):
        missing_data("no ../shared")
    monkeypatch.setenv("CI", "")
    with pytest.raises(pytest.skip.Exception, match="no ../shared"):
        missing_data("no ../shared")
