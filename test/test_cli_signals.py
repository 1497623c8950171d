# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""SIGTERM ends every long verb like Ctrl-C: exit 143, nothing half-written left behind."""

import os
from pathlib import Path
import signal
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.slow  # over a few seconds each: left out by -m "not slow"


def _run_until_partial(args, folder: Path, timeout: float = 120.0):
    """Start ``robot-calib args``; SIGTERM it once a hidden partial output shows up."""
    env = dict(os.environ, PYTHONUNBUFFERED='1')
    proc = subprocess.Popen([sys.executable, '-m', 'robot_calib.cli', *args], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        if any(p.name.startswith('.') and 'partial' in p.name for p in folder.iterdir()):
            time.sleep(0.3)  # well inside the work
            break
        time.sleep(0.05)
    if proc.poll() is not None:
        pytest.skip('the verb finished before it could be interrupted (machine too fast)')
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    return proc.returncode, err


def test_sigterm_during_replay_leaves_nothing(tmp_path):
    sim = pytest.importorskip('robot_calib.sim')
    bag = tmp_path / 'drive'
    sim.simulate('fusion_drive', bag, seed=2, duration=600.0)
    before = set(os.listdir(tmp_path))
    code, err = _run_until_partial(['replay', str(bag), '--out', str(tmp_path / 'out'),
                                    '--no-progress'], tmp_path)
    assert code == 143, err
    assert 'terminated' in err and 'Traceback' not in err
    assert set(os.listdir(tmp_path)) == before


def test_sigterm_during_simulate_leaves_nothing(tmp_path):
    code, err = _run_until_partial(['simulate', 'fusion_drive', '--out', str(tmp_path / 'sim'),
                                    '--duration', '3600'], tmp_path)
    assert code == 143, err
    assert os.listdir(tmp_path) == []
