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


@pytest.fixture(scope="session")
def xia_tiny(xia_dir, tmp_path_factory) -> dict[str, Path]:
    """A tiny generator (two epochs), the same with a style encoder, and a tiny path walker (four steps)
    fitted on twelve real Xia walks (neutral and old): a humanoid with arms, which the synthetic skeleton
    has not. Good for running commands, not for quality."""
    import tiny

    root = tmp_path_factory.mktemp("xia_tiny")
    (root / "xia").mkdir()
    for style in ("neutral", "old"):
        for content in (1, 2, 3, 5, 6, 7):
            name = f"{style}_{content:02d}_000.bvh"
            (root / "xia" / name).symlink_to(xia_dir / name)
    models = {"generator": tiny.generator(root, epochs=2, timesteps=20), "walker": tiny.walker(root)[1]}
    models["style_codes"] = tiny.generator(root, epochs=2, timesteps=20, style_code_dim=16, name="codes")
    return models


@pytest.fixture
def empty_folder(tmp_path, monkeypatch) -> Path:
    """The working folder, empty: whatever the API writes unasked would show up here."""
    folder = tmp_path / "work"
    folder.mkdir()
    monkeypatch.chdir(folder)
    return folder


# Tiny checkpoints on synthetic data (no real data needed), trained once a session: the API tests and
# the same-outputs test run the commands on them.
@pytest.fixture(scope="session")
def styled(tmp_path_factory) -> Path:
    import synthetic
    import tiny

    root = tmp_path_factory.mktemp("styled")
    synthetic.xia_like_folder(root, walk_clips=6, frames=240)
    return tiny.generator(root, epochs=5)


@pytest.fixture(scope="session")
def walker(tmp_path_factory) -> Path:
    import synthetic
    import tiny

    root = tmp_path_factory.mktemp("walker")
    synthetic.xia_like_folder(root, walk_clips=8, frames=240)
    return tiny.walker(root)[1]


@pytest.fixture(scope="session")
def gestures(tmp_path_factory) -> tuple[Path, Path]:
    import tiny

    return tiny.gestures(tmp_path_factory.mktemp("gestures"))
