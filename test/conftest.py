# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Shared pytest fixtures; DDS kept on this machine and on a domain of this test run."""

import os
from pathlib import Path
import subprocess
import sys

import pytest

# Before rclpy is imported anywhere: discovery stays on localhost, and a domain id derived from
# the process id keeps parallel test runs on one machine from hearing each other.
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))

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


@pytest.fixture
def ros():
    """Initialise rclpy for one test and shut it down after."""
    import rclpy
    rclpy.init()
    yield
    rclpy.try_shutdown()


@pytest.fixture
def fresh_python():
    """Return ``run(code)``: the stripped stdout of ``code`` run in a new interpreter."""
    def run(code: str) -> str:
        return subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                              check=True).stdout.strip()
    return run
