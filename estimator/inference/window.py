"""The model's input window: a patch of the gel in metres that belongs to the model, and how far a
sensor's depth grid lies from what the model was trained on.

A model reads depth resampled onto its own window (``variant.window_m``, (height, width) in m,
centred on the pad; the input pitch is the window over ``size_px``), not onto one sensor's pixels,
so a contact has its physical size on any sensor (:func:`window_images`). A sensor whose grid is
much coarser than that pitch, or whose pad covers little of the window, is outside what the model
was trained on (:func:`input_range`): refused, or answered with a wider interval and the reason.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from estimator.errors import ModelError

__all__ = [
    "COVERAGE_WIDENING",
    "EDGE_WIDENING",
    "MAX_PITCH_RATIO",
    "MIN_COVERAGE",
    "InputRange",
    "input_range",
    "window_bounds",
    "window_images",
]

#: A depth grid coarser than this many times the model's input pitch is refused: the model would
#: read detail the sensor cannot give (its input would be an upsampled, blurred contact).
MAX_PITCH_RATIO = 1.5
#: A pad covering less than this share of the model's window widens the interval...
MIN_COVERAGE = 0.8
#: ... by this factor on the calibrated interval scale (the rest of the window reads as untouched gel).
COVERAGE_WIDENING = 1.5
#: A contact reaching the edge of a pad smaller than the window (cut off where the model expects gel)
#: widens the interval by this factor (on top of :data:`COVERAGE_WIDENING`).
EDGE_WIDENING = 1.5


def window_bounds(shape: tuple[int, int], pitch_m: float, window_m: tuple[float, float]
                  ) -> tuple[tuple[int, int], tuple[int, int]]:
    """((row_start, row_stop), (col_start, col_stop)) of a window of ``window_m`` (height, width; m)
    on a grid of ``shape`` (rows, cols) at ``pitch_m``, in grid pixels, centred on the grid's centre.

    Each extent is rounded to whole pixels (at least one); the start is ``floor((n - extent) / 2)``,
    negative (and the stop beyond the grid) where the window is larger than the grid.
    """
    bounds = []
    for n, side in zip(shape, window_m, strict=True):
        extent = max(1, round(side / pitch_m))
        start = (int(n) - extent) // 2
        bounds.append((start, start + extent))
    return bounds[0], bounds[1]


def window_images(images: np.ndarray, pitch_m: float, window_m: tuple[float, float]) -> np.ndarray:
    """The window ``window_m`` (height, width; m) of each image of a stack at ``pitch_m``, centred on
    the images' centre (:func:`window_bounds`): cut out where the images are larger, surrounded by
    zeros where they are smaller; ``images`` itself when the window is the whole image.

    ``images`` is (n, H, W) or (n, H, W, C).
    """
    if not (math.isfinite(pitch_m) and pitch_m > 0):
        raise ModelError(f"pixel pitch {pitch_m!r} m: expected a finite value > 0")
    shape = images.shape[1:3]
    bounds = window_bounds(shape, pitch_m, window_m)
    if all(b == (0, n) for b, n in zip(bounds, shape, strict=True)):
        return images
    (r0, r1), (c0, c1) = bounds
    out = np.zeros((images.shape[0], r1 - r0, c1 - c0, *images.shape[3:]), dtype=images.dtype)
    src_r, src_c = slice(max(r0, 0), min(r1, shape[0])), slice(max(c0, 0), min(c1, shape[1]))
    out[:, src_r.start - r0:src_r.stop - r0, src_c.start - c0:src_c.stop - c0] = images[:, src_r, src_c]
    return out


@dataclass(frozen=True)
class InputRange:
    """How one grasp's depth grid fits a model's input window (:func:`input_range`); falsy when the
    model must not answer.

    Attributes
    ----------
    coverage : float
        Share of the window the pad covers (1: the pad fills it; the rest reads as untouched gel).
    pitch_ratio : float or None
        The depth grid's pitch over the model's finest input pitch (None: not known).
    refusal : str
        Why the model must not answer (empty when it may).
    notes : tuple of str
        Why its interval is widened.
    widen : float
        Factor (>= 1) on the calibrated interval scale.
    """

    coverage: float = 1.0
    pitch_ratio: float | None = None
    refusal: str = ""
    notes: tuple[str, ...] = ()
    widen: float = 1.0

    def __bool__(self) -> bool:
        return not self.refusal

    @property
    def reasons(self) -> list[str]:
        """The refusal (if any), then the notes."""
        return [r for r in (self.refusal, *self.notes) if r]


def _mm(pair: Sequence[float]) -> str:
    return " x ".join(f"{v * 1e3:.2f}" for v in pair) + " mm"


def input_range(window_m: tuple[float, float], size_px: tuple[int, int], *, pitch_m: float,
                grid_shape: tuple[int, int], touches_edge: bool = False) -> InputRange:
    """Whether a depth grid of ``grid_shape`` (rows, cols) at ``pitch_m`` lies within what a model of
    input window ``window_m`` at ``size_px`` was trained on, and how far its interval must widen.

    * The grid's pitch above :data:`MAX_PITCH_RATIO` times the model's finest input pitch: refused
      (the model would read detail the sensor cannot give).
    * The pad covering less than :data:`MIN_COVERAGE` of the window: the interval widens by
      :data:`COVERAGE_WIDENING`.
    * ``touches_edge`` (the contact region reaches the grid's border in a sampled frame:
      :attr:`~estimator.features.ContactFeatures.touches_edge`) while the pad is smaller than the
      window along either side: the contact is cut off where the model expects gel; the interval
      widens by :data:`EDGE_WIDENING`. (Where the pad fills the window, as on the training sensor,
      a contact cut by the window's edge is what the model was trained on.)
    """
    model_pitch = min(w / n for w, n in zip(window_m, size_px, strict=True))
    ratio = pitch_m / model_pitch
    bounds = window_bounds(grid_shape, pitch_m, window_m)
    coverage = math.prod((min(stop, n) - max(start, 0)) / (stop - start)
                         for (start, stop), n in zip(bounds, grid_shape, strict=True))
    smaller = any(start < 0 or stop > n for (start, stop), n in zip(bounds, grid_shape, strict=True))
    pad = tuple(n * pitch_m for n in grid_shape)
    refusal = ""
    if ratio > MAX_PITCH_RATIO:
        refusal = (f"the depth grid's pitch {pitch_m * 1e3:.3f} mm is {ratio:.2f} times the model's input pitch "
                   f"{model_pitch * 1e3:.3f} mm (at most {MAX_PITCH_RATIO:g} times): the model would read detail "
                   "this sensor does not resolve (a finer depth grid, estimator.depth_binning, or another model)")
    notes, widen = [], 1.0
    if coverage < MIN_COVERAGE:
        notes.append(f"the {_mm(pad)} pad covers {coverage:.0%} of the model's {_mm(window_m)} window (less than "
                     f"{MIN_COVERAGE:.0%}; the rest reads as untouched gel)")
        widen *= COVERAGE_WIDENING
    if smaller and touches_edge:
        notes.append(f"the contact reaches the edge of the {_mm(pad)} pad, smaller than the model's "
                     f"{_mm(window_m)} window: the model sees it cut off")
        widen *= EDGE_WIDENING
    return InputRange(coverage=float(coverage), pitch_ratio=float(ratio), refusal=refusal, notes=tuple(notes),
                      widen=widen)
