"""What the reports print is readable: the session report's axes figure has no label on top of
another, and the diagnosis page shows fitted array parameters (g-sensitivity's G) as numbers with
units, on the shared styled page."""

import itertools

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg

from station.diagnose.effects import Fitted
from station.diagnose.model import parameters
from station.report.diagnosis import html_report, text
from station.report.session import axes_figure
from station.sim.layouts import A_MODEL


def _label_boxes(fig) -> list:
    """(text, window extent) of every non-empty text drawn in the axes of `fig`, laid out as the
    report lays it out (station.report.html.png)."""
    canvas = FigureCanvasAgg(fig)
    fig.tight_layout()
    canvas.draw()
    renderer = canvas.get_renderer()
    return [(t.get_text(), t.get_window_extent(renderer)) for ax in fig.axes for t in ax.texts
            if t.get_text()]


def test_axes_figure_labels_do_not_overlap():
    # Rupniewski's 12-gyro layout, each axis tilted by a milliradian as a calibration finds it:
    # four sensors along each of x, y, z (their labels once overprinted) and a 3-D view
    rng = np.random.default_rng(0)
    a = A_MODEL + 1e-3 * rng.standard_normal(A_MODEL.shape)
    unit = a / np.linalg.norm(a, axis=0)
    names = [f"g{i + 1}" for i in range(unit.shape[1])]
    fig = axes_figure(unit, names)
    boxes = _label_boxes(fig)
    for (s, p), (t, q) in itertools.combinations(boxes, 2):
        assert not p.overlaps(q), (s, t)
    # every sensor is named once in the 3-D view
    view = [n for t in fig.axes[0].texts for n in t.get_text().split(", ")]
    assert sorted(view) == sorted(names)


def _doc(params: dict) -> dict:
    """A diagnosis document (station.report.diagnosis.to_dict's layout) with one step."""
    return {"session": "unit.h5", "effects": list(params), "alpha": 0.01,
            "steps": [{"model": ["nominal", *params], "gap": {"between": 1.02},
                       "evidence": {}, "chosen": "none", "parameters": params}]}


def test_a_fitted_matrix_is_shown_as_numbers_with_its_unit():
    g = np.arange(9.0).reshape(3, 3) * 1e-5
    fitted = Fitted("g_sensitivity", {"G": g}, {"G": np.full((3, 3), 2e-6)}, 9,
                    units={"G": "rad/s per m/s^2"})
    doc = _doc({"g_sensitivity": parameters(fitted)})
    shown = text(doc)
    assert "{}" not in shown
    assert "g_sensitivity G = 0 1e-05 2e-05; 3e-05 4e-05 5e-05; 6e-05 7e-05 8e-05 +- 2e-06" in shown
    assert shown.rstrip().endswith("rad/s per m/s^2")
    page = html_report(doc)
    assert "<style>" in page and '<section id="parameters">' in page
    assert "<td>3e-05 4e-05 5e-05" not in page  # one cell per parameter, rows joined by ;
    assert "<td>0 1e-05 2e-05; 3e-05 4e-05 5e-05; 6e-05 7e-05 8e-05</td>" in page
    assert "<td>rad/s per m/s^2</td>" in page


def test_a_scalar_without_a_unit_and_an_undefined_sigma():
    fitted = Fitted("latency", {"delay": np.array([1e-3, 2e-3])}, {}, 2)
    shown = text(_doc({"latency": parameters(fitted)}))
    assert "latency delay = 0.001 0.002 +- nan" in shown
