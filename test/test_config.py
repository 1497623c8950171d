# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""config/robot_calib.yaml is generated from the params dataclasses and documents every key."""

from pathlib import Path

from robot_calib import config_gen, methods
from robot_calib.core.params import describe, flatten_nested, from_flat
import yaml

REPO = Path(__file__).resolve().parent.parent
CONFIG = REPO / 'config' / 'robot_calib.yaml'


def test_config_file_is_up_to_date():
    """Regenerate with `make config` when this fails."""
    assert CONFIG.read_text() == config_gen.render()


def test_every_node_has_a_section_and_every_key_a_comment_with_default():
    tree = yaml.safe_load(CONFIG.read_text())
    for name in methods.available():
        params = flatten_nested(tree[f'/**/{name}']['ros__parameters'])
        cls = methods.load(name).params_type
        expected = {i.name for i in describe(cls)}
        assert expected <= set(params), name
        assert 'mode' in params, f'{name} has no mode parameter'
        from_flat(cls, {k: v for k, v in params.items() if k in expected})
    lines = CONFIG.read_text().splitlines()
    for i, line in enumerate(lines):
        stripped = line.strip()
        if stripped and not stripped.startswith('#') and not stripped.endswith(':'):
            assert lines[i - 1].strip().startswith('#') and '(default' in lines[i - 1], line


def test_replay_reads_the_shipped_file_as_the_readme_says():
    """`robot-calib replay BAG --params config/robot_calib.yaml` (it refused output_dir)."""
    from robot_calib.replay.config import load_params_file, params_for
    loaded = load_params_file(CONFIG)
    for name in methods.available():
        params = params_for(name, methods.load(name), loaded, {})
        assert params == methods.load(name).params_type()   # the file holds the defaults
