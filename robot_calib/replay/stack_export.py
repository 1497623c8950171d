# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
A replay's calibration results in the form the robot's own stack takes: ``DIR/stack/``.

Each node's :meth:`~robot_calib.pipelines.base.Pipeline.stack_export` gives
its files (ros2_control controller parameters, static transforms, URDF joints,
a gyro bias; :mod:`robot_calib.pipelines.stack_export`); this writes them,
each header naming the node and the bags, and returns what ``summary.json``
lists under ``stack``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Sequence, Union

from robot_calib.pipelines.stack_export import FOLDER
from robot_calib.replay.select import Plan


def recording_of(bags: Sequence[Union[str, os.PathLike]]) -> str:
    """Return the bags as the headers name them (absolute paths)."""
    return ', '.join(str(Path(b).absolute()) for b in bags)


def write_stack(plan: Plan, tmp: Path, bags: Sequence[Union[str, os.PathLike]]
                ) -> tuple[dict[str, str], dict[str, Any]]:
    """
    Write each node's stack files into ``tmp/stack``.

    :returns: ({'stack/<file>': node}, the ``stack`` entry of summary.json:
        ``{'folder', 'files': {file: node}, 'withheld': [sentence]}``)
    """
    recording = recording_of(bags)
    files: dict[str, str] = {}
    withheld: list[str] = []
    for run in plan.runs:
        run.pipeline.recording = recording
        try:
            export = run.pipeline.stack_export()
        except Exception as exc:  # noqa: B902 - counted, never fatal
            run.error('stack_export', exc)
            continue
        withheld.extend(export.withheld)
        for name, text in export.files.items():
            if Path(name).name != name or name.startswith('.'):
                run.error('stack_export', ValueError(f'bad stack file name {name!r}'))
                continue
            if f'{FOLDER}/{name}' in files:
                name = f'{run.name}_{name}'
            folder = tmp / FOLDER
            folder.mkdir(exist_ok=True)
            (folder / name).write_text(text)
            if name.endswith('.sh'):
                os.chmod(folder / name, 0o755)
            files[f'{FOLDER}/{name}'] = run.name
    return files, {'folder': FOLDER, 'files': dict(sorted(files.items())),
                   'withheld': withheld}
