# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Package set-up for robot_calib (ament_python)."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'robot_calib'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='robot_calib maintainers',
    maintainer_email='maintainers@robot-calib.dev',
    description='Gyro, tilt, fusion and wheel calibration for low-cost wheeled robots.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'gyro_line_calibration = robot_calib.nodes.gyro_line_calibration:main',
            'loop_closure_correction = robot_calib.nodes.loop_closure_correction:main',
            'tilt_detection = robot_calib.nodes.tilt_detection:main',
            'odometry_fusion = robot_calib.nodes.odometry_fusion:main',
            'wheel_odometry_calibration = robot_calib.nodes.wheel_odometry_calibration:main',
            'robot-calib = robot_calib.cli:main',
        ],
    },
)
