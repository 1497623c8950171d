# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Parameters of the mismatch analyser (the single source of its defaults)."""

from __future__ import annotations

from dataclasses import dataclass

from robot_calib.core.params import param


@dataclass
class MismatchParams:
    """Parameters of the mismatch analyser."""

    mode: str = param('improved', '', "'improved' (windows, alternatives, exact refinement) "
                      "or 'seed' (global effects only, no windows)",
                      choices=('improved', 'seed'))
    margin: float = param(12.0, '', 'BIC gain an effect must bring to be considered',
                          minimum=0.0)
    alt_margin: float = param(10.0, '', 'BIC distance within which another effect is listed '
                              'as an alternative', minimum=0.0)
    max_lag: float = param(0.5, 's', 'largest time offset searched by cross-correlation',
                           minimum=0.0)
    min_correspondence: float = param(0.4, '', 'least correlation (0..1) of the moving real '
                                      'channels with the simulated ones; below it the two '
                                      'recordings are refused as not the same run',
                                      minimum=0.0, maximum=1.0)
    min_window: float = param(0.03, '', 'shortest effect window as a fraction of the recording',
                              minimum=0.0, maximum=1.0)
    min_window_s: float = param(2.0, 's', 'shortest effect window', minimum=0.0)
    noise_smooth: float = param(2.0, 's', 'moving average removed before measuring the noise',
                                minimum=0.0)
    heldout_chunks: int = param(60, '', 'chunks of the time line; every third is held out',
                                minimum=3)
    max_terms: int = param(14, '', 'most effects selected per topic', minimum=1)
    alpha: float = param(1e-6, '', 'false-alarm probability of the block-robust test an '
                         'effect must pass', minimum=1e-15, maximum=0.5)
    window_alpha: float = param(1e-3, '', 'false-alarm probability of the block-robust test '
                                'that a windowed effect changes at its window edges; a window '
                                'that fails it is reported over the whole recording',
                                minimum=1e-15, maximum=0.5)
    gain_band_s: float = param(0.25, 's', 'moving average splitting a gain (scale, cross-axis) '
                               'into slow and fast motion; a gain whose two parts differ by the '
                               'block-robust test while the slow one fails it is not reported '
                               '(0: no such test)', minimum=0.0)
    blocks: int = param(40, '', 'contiguous blocks of the time line for the block-robust '
                        'tests', minimum=4)
    min_block_s: float = param(1.0, 's', 'shortest block of the block-robust tests',
                               minimum=0.0)
    min_confidence: float = param(0.5, '', 'least evidence (0..1) of a reported finding; '
                                  'weaker ones are listed apart as weak_findings',
                                  minimum=0.0, maximum=1.0)
    min_improvement: float = param(0.002, '', 'least fraction by which a reported finding '
                                   'lowers the residual RMSE, on the fitted part and on held-out '
                                   'time; findings that do not are listed as weak_findings',
                                   minimum=0.0, maximum=1.0)
    floor_scale: float = param(1.0, '', "multiplies each effect's reporting floor (the "
                               'smallest size worth naming); smaller effects are listed as '
                               'minor_findings; 0 reports every significant effect',
                               minimum=0.0)
    drive_model: bool = param(True, '', 'fit the drive chain (dead time, first- or '
                              'second-order lag, gain, deadband, rate limit, turn-coupled speed '
                              'loss) on odometry speed and turn rate and on wheel joint rates '
                              'before the amplitude effects')
    drive_wheel_cap: bool = param(True, '', 'look for a wheel-speed cap on a differential '
                                  'drive odometry (speed and turn rate shrinking together) '
                                  "and on two wheel joints' rates (both slowing together)")
    drive_alpha: float = param(1e-3, '', 'false-alarm probability of the held-out chunk test '
                               'a part of the drive model must pass', minimum=1e-15,
                               maximum=0.5)
    drive_max_dead_time: float = param(0.5, 's', 'largest drive dead time searched',
                                       minimum=0.0)
    drive_jackknife_groups: int = param(8, '', 'contiguous groups of the fitted time line, '
                                        'each left out in turn to give the standard deviation '
                                        "of each drive part's value (block jackknife of the "
                                        'final fit); under 3: none', minimum=0)
