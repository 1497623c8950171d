# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Report figures drawn straight on matplotlib's Agg canvas, without pyplot.

Fleets replay many short bags, so a report's plots are a large share of a
short replay: pyplot's global figure manager and a layout pass
(``tight_layout`` draws every figure twice) cost more than the drawing. Here a
figure is a plain :class:`matplotlib.figure.Figure` on its own Agg canvas with
fixed margins, drawn once when saved; nothing global is touched, so figures can
be drawn from any thread. matplotlib is imported on first use (about 0.35 s).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Union

MARGINS_INCH = {'left': 0.75, 'right': 0.2, 'bottom': 0.55, 'top': 0.4}
"""Room around the grid of axes (inch): tick labels and axis labels, the title on top."""
MAX_TICK_INTERVALS = 5
"""At most this many intervals between major ticks on a linear axis (matplotlib: up to 9).

Ticks are artists of their own (two lines and two texts each), so they are a
large part of drawing a small report figure: 5 reads as well and saves about
a tenth of the plotting time."""


def available() -> bool:
    """Return whether matplotlib can be imported."""
    try:
        import matplotlib  # noqa: F401 - probing the optional plotting dependency
    except ImportError:
        return False
    return True


def new_figure(width: float, height: float, rows: int = 1, cols: int = 1) -> tuple[Any, Any]:
    """
    Return ``(figure, axes)`` of a ``width`` x ``height`` inch figure with a rows x cols grid.

    ``axes`` is one Axes for a 1 x 1 grid, else an array as ``Figure.subplots`` gives.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator
    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    m = MARGINS_INCH
    fig.subplots_adjust(left=m['left'] / width, right=1.0 - m['right'] / width,
                        bottom=m['bottom'] / height, top=1.0 - m['top'] / height,
                        wspace=0.3, hspace=0.35)
    axes = fig.subplots(rows, cols, squeeze=True)
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_locator(MaxNLocator(MAX_TICK_INTERVALS, steps=[1, 2, 2.5, 5, 10]))
    return fig, axes


def log_y(ax: Any) -> None:
    """
    Give ``ax`` a logarithmic y axis labelled in plain text (``1e-3``, ``1``, ``1e2``).

    matplotlib's default labels (``$10^{-3}$``) go through its TeX parser, whose
    first use costs about 0.1 s of a short replay.
    """
    from matplotlib.ticker import FuncFormatter, NullFormatter
    ax.set_yscale('log')
    ax.yaxis.set_major_formatter(FuncFormatter(lambda value, _pos: _power_label(value)))
    ax.yaxis.set_minor_formatter(NullFormatter())


def _power_label(value: float) -> str:
    """Return ``1e<n>`` for a power of ten (``1`` for 10^0), else the number as ``%g``."""
    if value > 0:
        n = round(math.log10(value))
        if math.isclose(value, 10.0 ** n, rel_tol=1e-9):
            return '1' if n == 0 else f'1e{n}'
    return f'{value:g}'


def save(fig: Any, path: Union[str, Path], dpi: int = 90) -> str:
    """Draw ``fig`` into the PNG file ``path`` at ``dpi``, then empty it; return the file name."""
    fig.savefig(path, dpi=dpi)
    fig.clear()   # artists and their pixel buffers go now, not when the cyclic collector runs
    return Path(path).name
