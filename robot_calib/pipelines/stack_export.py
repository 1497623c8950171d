# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Calibration results in the form the robot's own ROS 2 stack takes.

Beside a method's own result (``wheel_calibration.yaml``), a pipeline may
offer files for the robot's configuration, written into a ``stack/`` folder
(by replay into its output folder, by the wheel calibration node into its
``output_dir``):

- a ros2_control ``diff_drive_controller`` parameter block (``wheel_separation``,
  ``wheel_radius``, ``left_wheel_radius_multiplier``,
  ``right_wheel_radius_multiplier``) or, for a steered drive wheel, a
  ``tricycle_controller`` block (``wheelbase``, ``wheel_radius``) with the
  steering offset and scale as a ros2_control ``SimpleTransmission`` snippet
  (``<offset>``, ``<mechanical_reduction>``: joint = actuator / reduction +
  offset), since the controller takes no steering offset;
- a sensor mounting as a ``static_transform_publisher`` command (Jazzy
  argument form) and a URDF ``<joint type="fixed">`` snippet;
- a gyro bias as a documented YAML (the common IMU filters, such as
  imu_filter_madgwick, take no bias parameter).

Every file starts with a comment saying which node wrote it, from which
recording, and how to use it. Only values the calibration backs are written:
a wheel calibration that is not ``converged`` writes no stack file (the reason
is in :attr:`StackFiles.withheld`), a mounting the node did not know is not
written either. Angles in rad, lengths in m; rpy as URDF and tf2 take them
(R = Rz(yaw) Ry(pitch) Rx(roll)).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import json
import math
import shlex
from typing import Any, Mapping, Optional, Sequence
from xml.sax.saxutils import quoteattr

import numpy as np
from robot_calib.core.geometry import quat_to_matrix

FOLDER = 'stack'
"""The folder (in a replay's output folder or a node's ``output_dir``) of the files."""


@dataclass
class StackFiles:
    """
    The stack files of one node: ``{file name: text}`` and why others were not written.

    ``withheld`` is '' when everything the node could offer was written, else a
    sentence per file group that was not.
    """

    files: dict = field(default_factory=dict)
    withheld: list = field(default_factory=list)

    def add(self, other: 'StackFiles') -> 'StackFiles':
        """Merge ``other`` into this one; return self."""
        self.files.update(other.files)
        self.withheld.extend(other.withheld)
        return self


def _num(x: float) -> str:
    """Return a number as YAML and URDF read it (9 significant digits; below 1e-12: 0)."""
    x = float(x)
    return f'{(x if abs(x) > 1e-12 else 0.0) + 0.0:.9g}'  # no '-0', no rounding dust


def header(node: str, recording: str, lines: Sequence[str], prefix: str = '# ') -> str:
    """Return the comment header of a stack file: the node, the recording, then ``lines``."""
    text = [f'Written by robot_calib {node} from {recording or "an unnamed recording"}.'] + \
        [ln for ln in lines if ln]
    # a name from the data (a frame, a bag path) must not end the comment early
    return ''.join(f'{prefix}{" ".join(ln.split())}'.rstrip() + '\n' for ln in text)


def _xml_comment(node: str, recording: str, lines: Sequence[str]) -> str:
    """Return the header as an XML comment (a double hyphen is not allowed inside one)."""
    body = header(node, recording, lines, prefix='  ').replace('--', '- -')
    return f'<!--\n{body}-->\n'


def rpy_from_matrix(rot: np.ndarray) -> tuple[float, float, float]:
    """Return (roll, pitch, yaw) rad of a rotation matrix, R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r = np.asarray(rot, dtype=float)
    pitch = math.asin(float(np.clip(-r[2, 0], -1.0, 1.0)))
    if abs(r[2, 0]) < 1.0 - 1e-9:
        roll = math.atan2(r[2, 1], r[2, 2])
        yaw = math.atan2(r[1, 0], r[0, 0])
    else:  # gimbal lock: the yaw takes it all
        roll = 0.0
        yaw = math.atan2(-r[0, 1], r[1, 1])
    return roll, pitch, yaw


def static_transform_script(node: str, recording: str, parent: str, child: str,
                            xyz: Sequence[float], rpy: Sequence[float],
                            notes: Sequence[str] = ()) -> str:
    """Return a shell script running tf2_ros ``static_transform_publisher`` (Jazzy arguments)."""
    args = ' '.join(f'--{k} {_num(v)}' for k, v in zip(('x', 'y', 'z'), xyz))
    args += ' ' + ' '.join(f'--{k} {_num(v)}' for k, v in zip(('roll', 'pitch', 'yaw'), rpy))
    return ('#!/bin/sh\n' + header(node, recording, [
        f'The transform {parent} -> {child} (x y z m, roll pitch yaw rad). Run this script, or',
        "put the same arguments in a launch file's static_transform_publisher node.",
        *notes]) +
        f'exec ros2 run tf2_ros static_transform_publisher {args} '
        f'--frame-id {shlex.quote(parent)} --child-frame-id {shlex.quote(child)}\n')


def urdf_joint(node: str, recording: str, parent: str, child: str, xyz: Sequence[float],
               rpy: Sequence[float], notes: Sequence[str] = ()) -> str:
    """Return a URDF fixed-joint snippet placing ``child`` in ``parent``."""
    return ('<?xml version="1.0"?>\n' + _xml_comment(node, recording, [
        f"A fixed joint placing {child} in {parent} (xyz m, rpy rad): paste it into the robot's",
        'URDF (xacro) in place of the joint that places this link now.', *notes]) +
        f'<joint name={quoteattr(child + "_joint")} type="fixed">\n'
        f'  <parent link={quoteattr(parent)}/>\n'
        f'  <child link={quoteattr(child)}/>\n'
        f'  <origin xyz="{" ".join(_num(v) for v in xyz)}" '
        f'rpy="{" ".join(_num(v) for v in rpy)}"/>\n'
        '</joint>\n')


def mounting_files(stem: str, node: str, recording: str, parent: str, child: str,
                   xyz: Sequence[float], rpy: Sequence[float],
                   notes: Sequence[str] = ()) -> dict:
    """Return ``{stem_static_tf.sh, stem_joint.urdf.xml}`` of one mounting."""
    return {f'{stem}_static_tf.sh': static_transform_script(node, recording, parent, child,
                                                            xyz, rpy, notes),
            f'{stem}_joint.urdf.xml': urdf_joint(node, recording, parent, child, xyz, rpy,
                                                 notes)}


def _finite(result: Mapping[str, Any], keys: Sequence[str]) -> bool:
    return all(isinstance(result.get(k), (int, float)) and math.isfinite(result[k])
               for k in keys)


def _std(result: Mapping[str, Any], key: str) -> str:
    s = result.get(f'{key}_std')
    return f' +- {float(s):.2g}' if isinstance(s, (int, float)) and math.isfinite(s) else ''


def wheel_files(result: Mapping[str, Any], node: str, recording: str, *,
                base_frame: str = 'base_link', lidar_frame: Optional[str] = None,
                lidar_mounting: Optional[tuple] = None, caveat: str = '',
                joints: Optional[Mapping[str, str]] = None) -> StackFiles:
    """
    Return the stack files of a wheel calibration result (the contract's flat keys).

    :param result: ``wheel_calibration.yaml`` as a dict (``drive_type``, estimates,
        their ``_std`` twins, ``verdict``)
    :param lidar_frame: the scans' frame (the child of the lidar transform)
    :param lidar_mounting: the nominal mounting ``(translation xyz m, rotation w x y z)``
        the calibration started from (``/tf_static``), or None: its height and its
        tilt (roll, pitch), which planar scan matching cannot see, are kept
    :param caveat: what the estimates are relative to (wheel turns from odometry)
    :param joints: joint names by role (``left``, ``right``, ``steering``, ``traction``)
    """
    out = StackFiles()
    verdict = str(result.get('verdict', ''))
    if verdict != 'converged':
        out.withheld.append(f'{node}: no controller or lidar file: the calibration is not '
                            f'converged ({verdict or "no verdict"})')
        return out
    notes = ['Calibration verdict: converged. Values +- one standard deviation in comments.']
    if caveat:
        notes.append(f'NOTE: {caveat}.')
    joints = dict(joints or {})
    drive = result.get('drive_type')
    if drive == 'differential' and _finite(result, ('left_wheel_radius', 'right_wheel_radius',
                                                    'track_width')):
        out.files['diff_drive_controller.yaml'] = _diff_drive(result, node, recording, notes,
                                                              joints)
    elif drive == 'steered_wheel' and _finite(result, ('wheel_radius', 'wheel_base')):
        out.files['tricycle_controller.yaml'] = _tricycle(result, node, recording, notes, joints)
        if _finite(result, ('steering_offset', 'steering_scale')):
            out.files['steering_transmission.urdf.xml'] = _steering_transmission(
                result, node, recording, notes, joints)
    else:
        out.withheld.append(f'{node}: no controller file: drive type {drive!r} without its '
                            'estimates')
    if lidar_frame and _finite(result, ('lidar_x', 'lidar_y', 'lidar_yaw')):
        out.files.update(_lidar(result, node, recording, base_frame, lidar_frame,
                                lidar_mounting, notes))
    elif not lidar_frame:
        out.withheld.append(f'{node}: no lidar file: the scans named no frame')
    return out


def _diff_drive(result: Mapping[str, Any], node: str, recording: str, notes: list,
                joints: Mapping[str, str]) -> str:
    left, right = float(result['left_wheel_radius']), float(result['right_wheel_radius'])
    radius = 0.5 * (left + right)
    names = [f'Wheel joints in the recording: left {joints["left"]}, right {joints["right"]}.'] \
        if joints.get('left') and joints.get('right') else []
    return header(node, recording, [
        "ros2_control diff_drive_controller parameters: load this file after the controller's",
        'own parameter file (a later file overrides the same keys), and rename the top key if',
        'your controller has another name. The effective wheel radii are wheel_radius times',
        'each multiplier.', *names, *notes]) + (
        'diff_drive_controller:\n'
        '  ros__parameters:\n'
        f'    wheel_separation: {_num(result["track_width"])}  # m'
        f'{_std(result, "track_width")}\n'
        '    wheel_separation_multiplier: 1.0\n'
        f'    wheel_radius: {_num(radius)}  # m, the mean of the two radii\n'
        f'    left_wheel_radius_multiplier: {_num(left / radius)}  # left radius '
        f'{_num(left)} m{_std(result, "left_wheel_radius")}\n'
        f'    right_wheel_radius_multiplier: {_num(right / radius)}  # right radius '
        f'{_num(right)} m{_std(result, "right_wheel_radius")}\n')


def _tricycle(result: Mapping[str, Any], node: str, recording: str, notes: list,
              joints: Mapping[str, str]) -> str:
    offset_note = []
    if _finite(result, ('steering_offset', 'steering_scale')):
        offset_note = [
            "tricycle_controller takes no steering offset or scale: the steering joint's",
            f'position must already be the true wheel angle. Found: true = '
            f'{_num(result["steering_scale"])} * reading + {_num(result["steering_offset"])} rad',
            f'(offset{_std(result, "steering_offset")}, scale{_std(result, "steering_scale")}).',
            'Apply it where the reading becomes the joint state: steering_transmission.urdf.xml',
            '(ros2_control SimpleTransmission), or your hardware interface / driver.']
    names = [f'Joints in the recording: steering {joints["steering"]}, traction '
             f'{joints["traction"]}.'] if joints.get('steering') and joints.get('traction') \
        else []
    return header(node, recording, [
        'ros2_control tricycle_controller parameters (a steered drive wheel): load this file',
        "after the controller's own parameter file, and rename the top key if your controller",
        'has another name.', *offset_note, *names, *notes]) + (
        'tricycle_controller:\n'
        '  ros__parameters:\n'
        f'    wheelbase: {_num(result["wheel_base"])}  # m, rear axle to the steered wheel'
        f'{_std(result, "wheel_base")}\n'
        f'    wheel_radius: {_num(result["wheel_radius"])}  # m, the traction wheel'
        f'{_std(result, "wheel_radius")}\n')


def _steering_transmission(result: Mapping[str, Any], node: str, recording: str,
                           notes: list, joints: Mapping[str, str]) -> str:
    scale, offset = float(result['steering_scale']), float(result['steering_offset'])
    joint = joints.get('steering') or 'steering_joint'
    return '<?xml version="1.0"?>\n' + _xml_comment(node, recording, [
        'The steering calibration as a ros2_control SimpleTransmission (inside the <ros2_control>',
        'or robot description): joint angle = actuator reading / mechanical_reduction + offset,',
        'so mechanical_reduction = 1 / steering_scale and offset = steering_offset (rad). If',
        'the reading already went through a transmission with reduction r0 and offset o0, use',
        'r0 / steering_scale and steering_scale * o0 + steering_offset instead. Rename the',
        'actuator to yours.', *notes]) + (
        f'<transmission name={quoteattr(joint + "_transmission")}>\n'
        '  <plugin>transmission_interface/SimpleTransmission</plugin>\n'
        f'  <actuator name={quoteattr(joint + "_actuator")} role="actuator1"/>\n'
        f'  <joint name={quoteattr(joint)} role="joint1">\n'
        f'    <mechanical_reduction>{_num(1.0 / scale)}</mechanical_reduction>\n'
        f'    <offset>{_num(offset)}</offset>\n'
        '  </joint>\n'
        '</transmission>\n')


def _lidar(result: Mapping[str, Any], node: str, recording: str, base_frame: str,
           lidar_frame: str, mounting: Optional[tuple], notes: list) -> dict:
    x, y, yaw = float(result['lidar_x']), float(result['lidar_y']), float(result['lidar_yaw'])
    found = [f'Found: x {_num(x)}{_std(result, "lidar_x")} m, y {_num(y)}{_std(result, "lidar_y")}'
             f' m, yaw {_num(yaw)}{_std(result, "lidar_yaw")} rad.']
    if mounting is not None:
        pos, quat = mounting
        rot = quat_to_matrix(np.asarray(quat, dtype=float))
        yaw0 = math.atan2(rot[1, 0], rot[0, 0])
        c, s = math.cos(yaw - yaw0), math.sin(yaw - yaw0)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ rot
        z = float(pos[2])
        kept = ["z, roll and pitch are those of the recording's /tf_static (planar scan",
                'matching cannot see them); x, y and yaw are calibrated.']
    else:
        rot = np.array([[math.cos(yaw), -math.sin(yaw), 0.0], [math.sin(yaw), math.cos(yaw), 0.0],
                        [0.0, 0.0, 1.0]])
        z = 0.0
        kept = ['The recording had no /tf_static for the lidar: z is 0 here and the scanner is',
                "taken as level; set z from the robot's drawing (planar scan matching cannot see",
                'it). x, y and yaw are calibrated.']
    return mounting_files('lidar', node, recording, base_frame, lidar_frame, (x, y, z),
                          rpy_from_matrix(rot), found + kept + notes)


def imu_mounting_files(stem: str, node: str, recording: str, parent: str,
                       child: Optional[str], rotation: Optional[np.ndarray], source: str,
                       translation: Optional[Sequence[float]] = None) -> StackFiles:
    """
    Return the static transform and URDF joint of an IMU mounting the node used.

    :param rotation: IMU -> base rotation (3x3), None when the node knew none
    :param source: where the node took it from (said in the header)
    :param translation: the IMU's position in ``parent`` (m), from ``/tf_static``; None
        when unknown (written as 0 with a note: these nodes do not need it)
    """
    out = StackFiles()
    if rotation is None or not child:
        out.withheld.append(f'{node}: no IMU mounting file: '
                            + ('no mounting was known' if rotation is None
                               else 'the IMU messages named no frame'))
        return out
    notes = [f'The mounting {node} used, from {source}; the node does not estimate it: this',
             'writes it in the form the rest of the stack reads, so that both agree.']
    if translation is None:
        translation = (0.0, 0.0, 0.0)
        notes.append("Position not known (0 here): set it from the robot's drawing.")
    out.files.update(mounting_files(stem, node, recording, parent, child, translation,
                                    rpy_from_matrix(rotation), notes))
    return out


def gyro_bias_file(name: str, node: str, recording: str, frame: str, axis: str,
                   bias: float, std: float, prior_std: float) -> StackFiles:
    """
    Return a documented YAML of a gyro bias estimate (rad/s), or why it was not written.

    Written only when the data narrowed the bias down (its standard deviation
    below half the prior's); the header says whether it differs from zero.
    """
    out = StackFiles()
    if not (math.isfinite(bias) and math.isfinite(std)) or not std < 0.5 * prior_std:
        out.withheld.append(f'{node}: no gyro bias file: the recording did not narrow the bias '
                            f'down (standard deviation {std:.2g} rad/s against the prior '
                            f'{prior_std:.2g}: the robot never stood still long enough)')
        return out
    differs = abs(bias) > 2.0 * std
    out.files[name] = header(node, recording, [
        f'The gyro bias {node} estimated: the rate the gyro reads at rest about {frame} {axis}',
        '(rad/s). Subtract it from the reading (corrected = reading - bias). The common IMU',
        'filters (imu_filter_madgwick, imu_complementary_filter, robot_localization) take no',
        'bias parameter: set it in the IMU driver where it has one, or subtract it in a small',
        'relay node. ' + ('It differs from zero by more than twice its standard deviation.'
                          if differs else 'It does not differ from zero by twice its standard '
                          'deviation: leaving the bias at 0 is as good.')]) + (
        'gyro_bias:\n'
        f'  frame_id: {json.dumps(frame)}\n'
        f'  axis: {axis}\n'
        f'  bias: {_num(bias)}  # rad/s\n'
        f'  bias_std: {_num(std)}  # rad/s\n'
        f'  differs_from_zero: {"true" if differs else "false"}\n')
    return out
