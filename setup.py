# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Package set-up for robot_calib (ament_python)."""

from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

package_name = 'robot_calib'
HERE = Path(__file__).resolve().parent
# One executable per method folder that has a node (robot_calib/methods/<executable>/node.py).
NODE_SCRIPTS = [f'{node.parent.name} = {package_name}.methods.{node.parent.name}.node:main'
                for node in sorted((HERE / package_name / 'methods').glob('*/node.py'))]

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools'],
    extras_require={'ray': ['ray']},  # robot-calib fleet --ray (see requirements-ray.txt)
    zip_safe=True,
    maintainer='robot_calib maintainers',
    maintainer_email='maintainers@robot-calib.dev',
    description='Gyro, tilt, fusion and wheel calibration for low-cost wheeled robots.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': NODE_SCRIPTS + ['robot-calib = robot_calib.cli:entry'],
    },
)
