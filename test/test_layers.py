# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The import direction of the package: core <- methods <- pipelines <- nodes, replay and CLI.

Each module is given a layer from its path; a layer may import only the layers
listed for it in :data:`ALLOWED` (and itself). Method folders may import only
their own modules, and a method's seed-faithful and improved variants never
import each other. The methods (their estimators and ``robot_calib.methods``, which
holds the registry) never import the pipelines, and the pipeline framework
(``robot_calib/pipelines/``) never imports the methods: a method's ``pipeline.py``
builds on the framework, so an import back would run in a circle.
"""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / 'robot_calib'

ALLOWED = {
    'core': {'core'},
    'codec': {'core', 'codec'},
    'io': {'core', 'codec', 'io'},
    'method': {'core', 'method'},
    'pipeline': {'core', 'method', 'pipeline'},
    'node': {'core', 'codec', 'method', 'pipeline', 'node'},
    'sim': {'core', 'codec', 'io', 'sim'},
    'mismatch': {'core', 'codec', 'io', 'sim', 'mismatch'},
    'app': {'core', 'codec', 'io', 'method', 'pipeline', 'node', 'sim', 'mismatch', 'app'},
}
"""Layer -> the layers it may import."""


def layer_of(module: str) -> str:
    """Return the layer of a dotted module name inside robot_calib."""
    parts = module.split('.')[1:]
    top = parts[0] if parts else ''
    if top == 'methods':
        if len(parts) >= 3 and parts[2] == 'pipeline':
            return 'pipeline'
        if len(parts) >= 3 and parts[2] == 'node':
            return 'node'
        return 'method'
    if top == 'pipelines':
        return 'pipeline'
    if top == 'nodes':
        return 'node'
    if top in ('core', 'codec', 'io', 'sim', 'mismatch'):
        return top
    return 'app'


def _module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix('')
    parts = list(rel.parts)
    if parts[-1] == '__init__':
        parts.pop()
    return '.'.join(parts)


def _imports(path: Path) -> set[str]:
    """Return the robot_calib modules ``path`` imports (``from X import y`` gives X.y too)."""
    tree = ast.parse(path.read_text())
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f'{node.module}.{a.name}' for a in node.names)
    return {m for m in found if m.startswith('robot_calib.')}


def _real(module: str) -> str:
    """Return ``module`` or, when it names an attribute, the module that holds it."""
    parts = module.split('.')
    while len(parts) > 1:
        path = PACKAGE.parent.joinpath(*parts)
        if path.with_suffix('.py').is_file() or (path / '__init__.py').is_file():
            return '.'.join(parts)
        parts.pop()
    return module


def _violations() -> list[str]:
    out = []
    for path in sorted(PACKAGE.rglob('*.py')):
        module = _module_name(path)
        layer = layer_of(module)
        for imported in sorted({_real(m) for m in _imports(path)}):
            target = layer_of(imported)
            if target not in ALLOWED[layer]:
                out.append(f'{module} ({layer}) imports {imported} ({target})')
            own = module.split('.')
            other = imported.split('.')
            if own[:2] == ['robot_calib', 'pipelines'] and other[:2] == ['robot_calib', 'methods']:
                out.append(f'{module}: the pipeline framework imports a method: {imported}')
            if layer == 'method' and target == 'method' and len(other) > 2 \
                    and len(own) > 2 and other[2] != own[2]:
                out.append(f'{module} imports another method: {imported}')
            if own[:2] == ['robot_calib', 'methods'] and len(own) == 4 and len(other) == 4 \
                    and own[2] == other[2] and {_variant(own[3]), _variant(other[3])} == {
                        'seed', 'improved'}:
                out.append(f'{module} and {imported}: variants import each other')
    return out


def _variant(name: str) -> str:
    return name.split('_')[0] if name.split('_')[0] in ('seed', 'improved') else ''


def test_layer_of_names_the_layers():
    """The classification the import rule relies on."""
    assert layer_of('robot_calib.core.geometry') == 'core'
    assert layer_of('robot_calib.methods.tilt_detection.seed') == 'method'
    assert layer_of('robot_calib.methods.tilt_detection.pipeline') == 'pipeline'
    assert layer_of('robot_calib.methods.tilt_detection.node') == 'node'
    assert layer_of('robot_calib.codec.cdr') == 'codec'
    assert layer_of('robot_calib.replay') == 'app'
    assert _variant('improved_gate') == 'improved' and _variant('common') == ''


def test_imports_go_one_way():
    """No module imports a layer above its own, another method, or the other variant."""
    assert _violations() == []


def test_the_rule_catches_a_wrong_import(tmp_path):
    """A core module importing a pipeline is reported (the check can fail)."""
    pkg = tmp_path / 'robot_calib'
    (pkg / 'core').mkdir(parents=True)
    (pkg / 'pipelines').mkdir()
    for init in (pkg, pkg / 'core', pkg / 'pipelines'):
        (init / '__init__.py').write_text('')
    (pkg / 'pipelines' / 'base.py').write_text('')
    (pkg / 'core' / 'bad.py').write_text('from robot_calib.pipelines.base import Pipeline\n')
    real = globals()['PACKAGE']
    globals()['PACKAGE'] = pkg
    try:
        assert _violations() == ['robot_calib.core.bad (core) imports '
                                 'robot_calib.pipelines.base (pipeline)']
    finally:
        globals()['PACKAGE'] = real


def _fake_package(tmp_path, files: dict) -> list[str]:
    """Return the violations of a package made of ``files`` (path -> text) under tmp_path."""
    pkg = tmp_path / 'robot_calib'
    for rel, text in files.items():
        path = pkg / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    for folder in [pkg, *[p for p in pkg.rglob('*') if p.is_dir()]]:
        if not (folder / '__init__.py').exists():
            (folder / '__init__.py').write_text('')
    real = globals()['PACKAGE']
    globals()['PACKAGE'] = pkg
    try:
        return _violations()
    finally:
        globals()['PACKAGE'] = real


def test_methods_and_the_pipeline_framework_do_not_import_each_other(tmp_path):
    """The registry in methods/ importing pipelines, or pipelines/ importing a method, fails."""
    assert _fake_package(tmp_path, {
        'methods/__init__.py': 'from robot_calib.pipelines import base\n',
        'pipelines/base.py': '',
    }) == ['robot_calib.methods (method) imports robot_calib.pipelines (pipeline)',
           'robot_calib.methods (method) imports robot_calib.pipelines.base (pipeline)']
    assert _fake_package(tmp_path / 'b', {
        'pipelines/__init__.py': 'from robot_calib import methods\n',
        'methods/__init__.py': '',
    }) == ['robot_calib.pipelines: the pipeline framework imports a method: robot_calib.methods']
    assert _fake_package(tmp_path / 'c', {
        'methods/tilt/pipeline.py': 'from robot_calib.pipelines.base import Pipeline\n',
        'pipelines/base.py': '',
    }) == []   # a method's adapter builds on the framework
