# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The README's offline examples run as written (those that need no data of the user's)."""

from pathlib import Path
import shlex

import pytest
from robot_calib.cli import main

README = Path(__file__).resolve().parents[1] / 'README.md'


def _examples(verb: str) -> list[list[str]]:
    out = []
    for line in README.read_text().splitlines():
        words = shlex.split(line.split('#')[0]) if line.startswith('    robot-calib ') else []
        if len(words) > 1 and words[1] == verb:
            out.append(words[1:])
    return out


@pytest.mark.slow
def test_simulate_then_replay_examples_run_as_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    sims = _examples('simulate')
    assert sims, 'the README lost its simulate example'
    for args in sims:
        assert main(args) == 0, args
    replays = [a for a in _examples('replay') if '--live' not in a and
               (tmp_path / a[1]).exists()]
    assert replays, 'no replay example of the simulated bag'
    for args in replays:
        assert main(args + ['--no-progress']) == 0, args
        assert (tmp_path / args[args.index('--out') + 1] / 'summary.json').exists()
    fleets = [a for a in _examples('fleet') if (tmp_path / a[1]).is_dir()]
    assert fleets, 'no fleet example of the simulated fleet'
    for args in fleets:
        assert main(args + ['--no-progress']) == 0, args
        assert (tmp_path / args[args.index('--out') + 1] / 'report.md').exists()


def test_sample_bag_examples_run_as_written(tmp_path, monkeypatch):
    bags = README.parent / 'bags'
    runs = [a for a in _examples('replay') if '--live' not in a and a[1].startswith('bags/')]
    if not runs or not all((README.parent / a[1]).exists() for a in runs):
        pytest.skip('sample bags not present')
    for args in runs:
        args = [str(bags.parent / a) if a.startswith('bags/') else a for a in args]
        args[args.index('--out') + 1] = str(tmp_path / Path(args[args.index('--out') + 1]).name)
        assert main(args + ['--no-progress']) == 0, args
