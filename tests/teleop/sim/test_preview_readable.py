"""``teleop simulate --preview``'s contact sheet is readable: about 100 dpi, a visible 'true tips'
line, and a depth colour range taken from the gel inside its rim, not from its bright rim."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from matplotlib.colors import to_rgb
from matplotlib.figure import Figure

import teleop.sim.preview as preview


@pytest.fixture
def drawn(monkeypatch):
    """The figures write_preview makes."""
    made: list[Figure] = []

    class Recorded(Figure):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            made.append(self)

    monkeypatch.setattr(preview, "Figure", Recorded)
    return made


def _grasp():
    """A record without frames and its truth: a 30 µm contact in a gel whose rim reads 0.45 mm."""
    t = np.linspace(0.0, 3.0, 301)
    force = np.interp(t, [0.0, 1.0, 1.5, 2.0, 2.5, 3.0], [0, 0, 20, 20, 0, 0])
    motor = np.interp(t, [0.0, 1.5, 2.0, 3.0], [0.08, 0.05, 0.05, 0.08])
    depth = np.full((100, 140), 0.01e-3)
    depth[40:60, 50:90] = 0.04e-3
    depth[:5], depth[-5:], depth[:, :5], depth[:, -5:] = 0.45e-3, 0.45e-3, 0.45e-3, 0.45e-3
    truth = SimpleNamespace(touch_s=1.0, stall_s=1.5, release_s=2.0, t_s=t, force_n=force, motor_width_m=motor,
                            tip_width_m=motor + force / 5e3, peak_gel_m={"left": depth, "right": depth})
    record = SimpleNamespace(frames=(), force_n=SimpleNamespace(t_s=t[::5], value=force[::5]),
                             width_m=SimpleNamespace(t_s=t[::10], value=motor[::10]), label=None,
                             provenance=SimpleNamespace(model="test"))
    return record, truth


def test_the_preview_is_drawn_at_about_100_dpi(drawn, tmp_path):
    path = preview.write_preview(*_grasp(), tmp_path / "p.png")
    (fig,) = drawn
    width_in = fig.get_size_inches()[0]
    assert cv2.imread(str(path)).shape[1] >= 95 * width_in  # 9 pt titles at least ~12 px high


def test_the_true_tips_line_shows_on_white(drawn, tmp_path):
    preview.write_preview(*_grasp(), tmp_path / "p.png")
    (fig,) = drawn
    (tips,) = [line for ax in fig.axes for line in ax.get_lines() if line.get_label() == "true tips"]
    assert min(to_rgb(tips.get_color())) < 0.5  # a colour, or a dark grey; not a pale one


def test_the_depth_colours_span_the_contact_not_the_rim(drawn, tmp_path):
    preview.write_preview(*_grasp(), tmp_path / "p.png")
    (fig,) = drawn
    images = [image for ax in fig.axes for image in ax.get_images()]
    assert len(images) == 2
    for image in images:
        low, high = image.get_clim()
        assert low == pytest.approx(0.01, abs=1e-6) and high == pytest.approx(0.04, abs=1e-6)
    bars = [ax for ax in fig.axes if "percentile" in ax.get_ylabel()]
    assert len(bars) == 2 and all("mm" in ax.get_ylabel() for ax in bars)
