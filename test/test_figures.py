# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Report figures: plain-text log axes (no TeX parsing), few ticks, and saving."""

import numpy as np
import pytest

from robot_calib.core import figures

pytest.importorskip('matplotlib')


@pytest.mark.parametrize('value, label', [(1e-3, '1e-3'), (1.0, '1'), (100.0, '1e2'),
                                          (0.5, '0.5'), (2e-7, '2e-07'), (0.0, '0')])
def test_power_label(value, label):
    assert figures._power_label(value) == label


def test_log_axis_labels_are_plain_text(tmp_path):
    fig, ax = figures.new_figure(4, 3)
    ax.plot(np.arange(50), np.logspace(-4, 1, 50))
    figures.log_y(ax)
    fig.canvas.draw()
    labels = [t.get_text() for t in ax.get_yticklabels() if t.get_text()]
    assert ax.get_yscale() == 'log'
    assert labels and all('$' not in text for text in labels)
    assert {'1e-3', '1'} <= set(labels)
    name = figures.save(fig, tmp_path / 'log.png')
    assert name == 'log.png' and (tmp_path / 'log.png').stat().st_size > 1000
    assert not fig.axes   # emptied after saving


def test_linear_axes_have_few_major_ticks():
    fig, ax = figures.new_figure(9, 3.5)
    ax.plot(np.linspace(0, 10, 200), np.linspace(0, -5, 200))
    fig.canvas.draw()
    for axis in (ax.xaxis, ax.yaxis):
        # matplotlib's default puts 8 ticks (6 in view) on each of these axes
        lo, hi = sorted(axis.get_view_interval())
        inside = [v for v in axis.get_majorticklocs() if lo <= v <= hi]
        assert len(inside) >= 3
        assert len(axis.get_majorticklocs()) <= figures.MAX_TICK_INTERVALS + 2
