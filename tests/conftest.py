"""Shared fixtures. Real-data tests skip on a laptop without the data, but fail in CI."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from walkdiff.common.paths import data_root

REQUIRE_DATA = bool(os.environ.get("CI") or os.environ.get("WALKDIFF_REQUIRE_DATA"))


def _real(name: str) -> Path:
    path = data_root() / name
    if not path.is_dir():
        msg = f"real data not found at {path.resolve()} (set WALKDIFF_DATA)"
        if REQUIRE_DATA:
            pytest.fail(msg)
        pytest.skip(msg)
    return path


@pytest.fixture(scope="session")
def xia_dir() -> Path:
    return _real("xia")


@pytest.fixture(scope="session")
def zeggs_dir() -> Path:
    return _real("zeggs")


@pytest.fixture(autouse=True)
def no_leaked_tracking_uri(monkeypatch):
    """Lightning's MLFlowLogger exports its URI as MLFLOW_TRACKING_URI for the rest of the process: each
    test starts, and ends, with the environment it was given."""
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
