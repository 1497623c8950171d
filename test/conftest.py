# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Shared pytest fixtures."""

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED_DATA = REPO.parent / 'shared' / 'data'


@pytest.fixture
def shared_data() -> Path:
    """Return ``../shared/data``; skip the test cleanly when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip('../shared/data is not present')
    return SHARED_DATA


@pytest.fixture
def repo_root() -> Path:
    """Return the repository root."""
    return REPO
