# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Shared pytest fixtures; DDS kept on this machine and on a domain of this test run."""

import importlib.util
import os
from pathlib import Path
import shutil
import subprocess
import sys

import pytest

# Before rclpy is imported anywhere: discovery stays on localhost, and a domain id derived from
# the process id keeps parallel test runs on one machine from hearing each other.
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))

REPO = Path(__file__).resolve().parent.parent
SHARED_DATA = REPO.parent / 'shared' / 'data'

# helpers shared by tests and benchmarks (benchmarks/tilt_onsets.py, mismatch_protocols.py, ...)
if str(REPO / 'benchmarks') not in sys.path:
    sys.path.insert(0, str(REPO / 'benchmarks'))


def _tf2_msgs_cannot_be_had() -> bool:
    """Return True where tf2_msgs is missing and the set-up had no tools to build it."""
    if importlib.util.find_spec('tf2_msgs') is not None:
        return False
    return any(shutil.which(tool) is None for tool in ('cmake', 'make', 'cc', 'c++'))


def pytest_collection_modifyitems(config, items) -> None:
    """
    Skip the tests marked ``needs_tf2_msgs`` on a machine that cannot build tf2_msgs.

    Where the build tools exist, a missing tf2_msgs is a broken set-up and those
    tests run (and fail).
    """
    if not _tf2_msgs_cannot_be_had():
        return
    skip = pytest.mark.skip(reason='tf2_msgs is not installed and cmake or a C/C++ compiler '
                                   'is missing to build it (tools/build_tf2_msgs.sh)')
    for item in items:
        if 'needs_tf2_msgs' in item.keywords:
            item.add_marker(skip)


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
