"""The episode figure's shading: what a reader sees in its legend."""

import numpy as np
from matplotlib.figure import Figure

from safeswitch.report.figures import _spans


def test_a_recurring_shade_has_one_legend_entry():
    # a filter that chatters on and off shades many intervals: one entry names them all
    ax = Figure().subplots()
    time = 0.1 * np.arange(1, 11)
    mask = np.array([1, 0, 1, 0, 1, 1, 0, 0, 1, 0], dtype=bool)
    _spans(ax, time, mask, color="r", label="safety action executed")
    _, labels = ax.get_legend_handles_labels()
    assert labels == ["safety action executed"]
    assert len(ax.patches) == 4  # every interval shaded
