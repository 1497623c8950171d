# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The ROS 2 package layout: manifest, colcon install, ``ros2 run`` lookup, README commands."""

import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import time

import pytest
from robot_calib import methods

REPO = Path(__file__).resolve().parent.parent
NODES = methods.names()
EXECUTABLES = NODES + ['robot-calib']


def test_package_xml_is_valid_format_3():
    """catkin_pkg parses package.xml: format 3, ament_python, a valid maintainer email."""
    from catkin_pkg.package import parse_package
    pkg = parse_package(str(REPO / 'package.xml'))
    pkg.validate()
    assert pkg.package_format == 3
    assert pkg.name == 'robot_calib'
    assert pkg.get_build_type() == 'ament_python'
    assert all('@' in m.email for m in pkg.maintainers)
    names = {d.name for d in pkg.exec_depends}
    assert {'rclpy', 'sensor_msgs', 'nav_msgs', 'diagnostic_msgs', 'geometry_msgs', 'std_msgs',
            'rosgraph_msgs', 'builtin_interfaces', 'rcl_interfaces', 'tf2_msgs',
            'python3-rosbags-pip', 'python3-kiss-icp-pip'} <= names


def test_setup_installs_scripts_where_ros2_run_looks():
    """setup.cfg installs console scripts into lib/robot_calib, as ros2 run expects."""
    cfg = (REPO / 'setup.cfg').read_text()
    assert 'install_scripts=$base/lib/robot_calib' in cfg
    assert 'script_dir=$base/lib/robot_calib' in cfg
    namespace = {'__file__': str(REPO / 'setup.py')}
    setup_text = (REPO / 'setup.py').read_text().split('setup(\n')[0]
    exec(compile(setup_text, 'setup.py', 'exec'), namespace)
    scripts = namespace['NODE_SCRIPTS']
    assert scripts == [f'{exe} = {methods.node_target(exe)}' for exe in sorted(NODES)]
    assert (REPO / 'resource' / 'robot_calib').is_file()


def _readme_commands():
    text = (REPO / 'README.md').read_text()
    return re.findall(r'^\s{4}(make \w+)', text, flags=re.MULTILINE)


def test_readme_commands_are_what_ci_and_make_use():
    """The README's two commands exist in the Makefile, and .ci/run calls the test command."""
    commands = _readme_commands()
    assert 'make demo' in commands and 'make test' in commands
    makefile = (REPO / 'Makefile').read_text()
    for cmd in ('demo', 'test'):
        assert re.search(rf'^{cmd}:', makefile, flags=re.MULTILINE), cmd
    assert re.search(r'^test:.*\n\t.*pytest', makefile, flags=re.MULTILINE)
    ci = (REPO / '.ci' / 'run').read_text()
    ci_commands = [ln.strip() for ln in ci.splitlines()
                   if ln.strip() and not ln.strip().startswith('#')]
    assert 'make test' in ci_commands
    assert os.access(REPO / '.ci' / 'run', os.X_OK)


def test_requirements_are_pinned():
    """Every requirement is pinned to one version, so a fresh machine gets what we tested."""
    for name in ('requirements.txt', 'requirements-bench.txt', 'requirements-build.txt'):
        for line in (REPO / name).read_text().splitlines():
            line = line.split('#')[0].strip()
            if line:
                assert re.fullmatch(r'[A-Za-z0-9_.\-]+==[\w.]+', line), f'{name}: {line}'


@pytest.fixture(scope='module')
def install_space(tmp_path_factory):
    """Build the package with colcon into a temporary install space."""
    colcon = Path(sys.executable).parent / 'colcon'
    if not colcon.exists():
        pytest.skip('colcon is not installed in this environment')
    base = tmp_path_factory.mktemp('colcon')
    cmd = [str(colcon), '--log-base', str(base / 'log'), 'build', '--base-paths', str(REPO),
           '--build-base', str(base / 'build'), '--install-base', str(base / 'install')]
    result = subprocess.run(cmd, cwd=base, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return base / 'install'


def _install_env(install: Path) -> dict:
    env = dict(os.environ)
    prefix = install / 'robot_calib'
    env['AMENT_PREFIX_PATH'] = os.pathsep.join(
        [str(prefix)] + [p for p in env.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p])
    site = next((prefix / 'lib').glob('python3*/site-packages'))
    env['PYTHONPATH'] = os.pathsep.join([str(site)] + [p for p in env.get(
        'PYTHONPATH', '').split(os.pathsep) if p])
    env.setdefault('ROS_DOMAIN_ID', '77')
    return env


@pytest.mark.slow
def test_colcon_install_is_found_like_ros2_run(install_space):
    """ament_index finds robot_calib and every executable sits in lib/robot_calib."""
    env = _install_env(install_space)
    code = ('from ament_index_python.packages import get_package_prefix;'
            'print(get_package_prefix("robot_calib"))')
    out = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    prefix = Path(out.stdout.strip().splitlines()[-1])
    assert prefix == install_space / 'robot_calib'
    for exe in EXECUTABLES:
        path = prefix / 'lib' / 'robot_calib' / exe
        assert path.is_file() and os.access(path, os.X_OK), exe
    assert (prefix / 'share' / 'robot_calib' / 'package.xml').is_file()
    assert (prefix / 'share' / 'robot_calib' / 'config' / 'robot_calib.yaml').is_file()


@pytest.mark.slow
def test_installed_node_starts_and_stops_cleanly(install_space):
    """Run an installed node executable, wait until it is up, interrupt it: exit status 0."""
    assert NODES, 'no method folder found'
    present = NODES
    exe = install_space / 'robot_calib' / 'lib' / 'robot_calib' / present[0]
    env = _install_env(install_space)
    env['PYTHONUNBUFFERED'] = '1'
    env['RCUTILS_LOGGING_BUFFERED_STREAM'] = '0'
    proc = subprocess.Popen([str(exe)], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        lines = []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if 'ready' in line:
                break
        assert any('ready' in ln for ln in lines), ''.join(lines)
        proc.send_signal(signal.SIGINT)
        rc = proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert rc == 0, ''.join(lines) + proc.stdout.read()


def test_launch_file_declares_every_node_and_the_params_file():
    """launch/robot_calib.launch.py parses, takes the installed params file, knows every node."""
    import ast
    path = REPO / 'launch' / 'robot_calib.launch.py'
    tree = ast.parse(path.read_text())
    functions = {f.name for f in tree.body if isinstance(f, ast.FunctionDef)}
    assert 'generate_launch_description' in functions
    args = {c.args[0].value for c in ast.walk(tree) if isinstance(c, ast.Call)
            and getattr(c.func, 'id', '') == 'DeclareLaunchArgument'}
    assert args == {'nodes', 'params_file', 'namespace', 'use_sim_time'}
    text = path.read_text()
    assert "'robot_calib.yaml'" in text and 'methods.names()' in text
    setup = (REPO / 'setup.py').read_text()
    assert "glob('launch/*.launch.py')" in setup
