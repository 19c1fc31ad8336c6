"""Shared fixtures: the independent sample set in ../shared/data (beside the checkout)."""

import json
from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
SAMPLE = SHARED / "data" / "paper-sample"
TRUTH = SHARED / "data" / "truth.json"


@pytest.fixture(scope="session")
def sample_set_path() -> Path:
    if not SAMPLE.is_dir():
        pytest.fail(f"the shared sample set is missing: {SAMPLE}")
    return SAMPLE


@pytest.fixture(scope="session")
def truth() -> dict:
    return json.loads(TRUTH.read_text())["paper-sample"]
