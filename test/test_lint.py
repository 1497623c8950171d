# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The ament linters as tests: flake8, pep257 and copyright headers."""

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
LINTED = ['robot_calib', 'test', 'benchmarks', 'launch', 'setup.py']
HEADER = ('# Copyright 2026 robot_calib contributors\n'
          '# SPDX-License-Identifier: Apache-2.0\n')


def _python_files():
    files = []
    for name in LINTED:
        path = REPO / name
        files.extend([path] if path.is_file() else sorted(path.rglob('*.py')))
    return files


@pytest.mark.linter
@pytest.mark.slow
def test_flake8(monkeypatch):
    """Run ament_flake8 over the package, its tests and benchmarks."""
    from ament_flake8.main import main_with_errors
    monkeypatch.chdir(REPO)
    rc, errors = main_with_errors(argv=LINTED)
    assert rc == 0, f'{len(errors)} flake8 errors:\n' + '\n'.join(errors[:30])


@pytest.mark.linter
@pytest.mark.slow
def test_pep257(monkeypatch):
    """Run ament_pep257 (the ament docstring convention)."""
    from ament_pep257.main import main
    monkeypatch.chdir(REPO)
    rc = main(argv=LINTED)
    assert rc == 0, 'pep257 errors: see the output above'


@pytest.mark.linter
def test_copyright_headers():
    """Every Python file starts with the copyright and SPDX licence lines."""
    missing = [str(p.relative_to(REPO)) for p in _python_files()
               if not p.read_text().startswith(HEADER)]
    assert missing == [], f'files without the copyright header: {missing}'
