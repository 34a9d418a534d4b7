"""The run-time learned estimate: grasp -> sampled frames -> analytical fits -> model -> Estimate.

:class:`HybridEstimator` measures a grasp exactly as the dataset builder did
(:func:`~estimator.inference.sampling.sample_stream`: the loading phase sampled at
the model's ``n_frames``, depth reconstructed for those frames only, contact
features, every analytical fit over them), from the live service's
:class:`~estimator.stream.GraspStream` or a record fed through one (one path: the same
floats either way), runs the ONNX model and returns an
:class:`~estimator.estimate.Estimate` with method ``"hybrid"`` (a model with
analytical inputs) or ``"cnn"`` (without). The model gives a distribution over
log10 E (:mod:`estimator.inference.distribution`): its calibrated interval about
the median holds the truth at the stated level (90 %,
``metadata.json`` ``calibration``); when the probability that E is at least the
sensor's resolution limit (:attr:`~teleop.settings.Settings.resolution_limit_pa`)
reaches the calibrated ``p_rigid``, the answer is a ``lower_bound`` at that
limit; a median below the softest training label gives an ``upper_bound``; otherwise the answer
is ``ok`` at the value the display should render (:func:`~estimator.inference.distribution.hedged_point`,
within that interval). The modulus is always finite and positive; a grasp that
cannot be sampled, or a model output that is not finite, gives a refusal with
its reason.

A grasp whose rig (gel modulus and thickness, finger stiffness: the record's settings) lies
outside the rigs the model was trained on (its ``data.rig_range``, give or take
:data:`RIG_RANGE_TOLERANCE`) has its interval widened :data:`RIG_WIDENING` times, and its reason
says which quantity and by how much.

The images are resampled onto the model's input window (:mod:`estimator.inference.inputs`,
"Input window"), and :func:`~estimator.inference.sampling.sampled_input_range` says whether the
sensor's depth grid lies within what the model was trained on: a grid much coarser than the
model's input pitch is refused (``insufficient_data``, the reason naming both pitches); a pad
covering little of the window, or a contact cut off by the edge of a pad smaller than the
window, widens the calibrated interval (its reason says why and by how much). A grasp whose
calibration smooths the colours (``estimator calibrate --smoothing-px``) otherwise than the
calibrations of the model's training data (``data.calibration_smoothing_px``; none for the shipped
models) is refused: smoothing changes how shallow slopes read, and the model reads depth only as it
was trained.

``auto`` mode
-------------
Per grasp, the cheapest answer whose expected error fits the budget:

1. The grasp cannot be sampled (no usable loading frame): a refusal that says what the
   force/width-only ``no_tactile`` fit reads (it cannot tell a soft object from a rigid one
   pressed into the gel, so it is never rendered). A grasp whose force and width give no
   loading phase (no contact, implausible forces) is refused with that reason alone: the
   frames are not what is missing.
2. The series-compliance fit is ``ok`` with an interval at most
   ``AutoPolicy.max_series_interval_decades`` wide, over at least
   ``MIN_SERIES_FRAMES`` distinct frames: that estimate, and the network is
   skipped. (A fit through fewer points has no scatter to show how far the
   contact model misses: its interval is the measurement resolution alone.)
   The threshold is chosen in training on the validation objects (the widest
   threshold at which the series fit's mean error on the grasps it accepts is no
   worse than the model's on the same grasps; ``metadata.json`` ``auto``),
   default 0.5 decade.
3. Otherwise the model. If the model fails or refuses the grasp (its sensor's grid
   outside the model's range), the first analytical estimate that is not a refusal, in
   the order series, hertz, elastic (no_tactile's, as in 1, only said).

The result's method is ``"auto"`` and its reason says which branch answered.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from estimator.analytical import METHODS
from estimator.errors import ModelError
from estimator.estimate import Estimate
from estimator.inference.distribution import Described
from estimator.inference.infer import CompliancePredictor
from estimator.inference.inputs import RIG_QUANTITIES, distinct_frames, gel_scale, smoothings_text
from estimator.inference.sampling import (
    SampledGrasp,
    record_stream,
    sample_stream,
    sampled_input_range,
)
from estimator.measurements import estimate_measurements
from estimator.perception.calibration import Calibration
from estimator.settings import estimator_settings
from estimator.stream import GraspStream
from teleop.record import GraspRecord
from teleop.settings import Settings

__all__ = ["ALL_METHODS", "FALLBACK_ORDER", "LEARNED_METHODS", "MIN_SERIES_FRAMES", "MODES", "RIG_RANGE_TOLERANCE", "RIG_WIDENING", "AutoPolicy", "HybridEstimator", "rig_notes"]

log = logging.getLogger(__name__)

#: The learned methods: a model's own (``hybrid``, with analytical inputs; ``cnn``, without) and ``auto``.
LEARNED_METHODS = ("cnn", "hybrid", "auto")
#: Every method an estimate can be asked for: the analytical fits, then the learned ones.
ALL_METHODS = (*METHODS, *LEARNED_METHODS)
MODES = ("model", "auto")
MIN_SERIES_FRAMES = 3
FALLBACK_ORDER = ("series", "hertz", "elastic", "no_tactile")
DEFAULT_SERIES_INTERVAL_DECADES = 0.5
#: Factor on the interval of a grasp whose rig lies outside the trained ones (as the window's widening).
RIG_WIDENING = 1.5
# Relative slack around a model's rig range: it records the extremes of the rigs drawn for training,
# which fall short of the range they were drawn from (120-400 kPa) by a fraction of a percent.
RIG_RANGE_TOLERANCE = 0.01
# How a reason names each of inputs.RIG_QUANTITIES: label, factor from SI, unit.
_RIG_LABELS = {"gel_modulus_pa": ("gel modulus", 1e-3, "kPa"), "gel_thickness_m": ("gel thickness", 1e3, "mm"),
               "finger_stiffness_n_per_m": ("finger stiffness", 1e-3, "kN/m")}


def rig_notes(sampled: SampledGrasp, rig_range: Mapping[str, Sequence[float]]) -> tuple[str, ...]:
    """Why ``sampled``'s rig lies outside ``rig_range`` (a model's ``data.rig_range``), one note per
    quantity; empty when it lies inside, :data:`RIG_RANGE_TOLERANCE` included, or where either side does
    not record the quantity."""
    notes = []
    for name in RIG_QUANTITIES:
        label, scale, unit = _RIG_LABELS[name]
        value, bounds = getattr(sampled, name), rig_range.get(name)
        if value is None or bounds is None:
            continue
        low, high = bounds[0] * (1 - RIG_RANGE_TOLERANCE), bounds[1] * (1 + RIG_RANGE_TOLERANCE)
        if not low <= value <= high:
            # Printed to 4 digits: a value more than the tolerance off a bound never prints as that bound.
            notes.append(f"{label} {value * scale:.4g} {unit} outside the {bounds[0] * scale:.4g}-"
                         f"{bounds[1] * scale:.4g} {unit} trained on (give or take {RIG_RANGE_TOLERANCE:.0%})")
    return tuple(notes)


def interval_decades(estimate: Estimate) -> float:
    """Width of an estimate's interval in decades (inf when a side is open)."""
    low, high = estimate.interval_pa
    return math.inf if low is None or high is None else math.log10(high / low)


@dataclass(frozen=True)
class AutoPolicy:
    """When ``auto`` answers with the series-compliance fit instead of the model.

    Attributes
    ----------
    max_series_interval_decades : float
        A series estimate in state ``ok`` whose interval is at most this many
        decades wide is returned as is; 0 never skips the model.
    """

    max_series_interval_decades: float = DEFAULT_SERIES_INTERVAL_DECADES

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_series_interval_decades) and self.max_series_interval_decades >= 0):
            raise ModelError(f"max_series_interval_decades {self.max_series_interval_decades!r}: expected >= 0")

    @classmethod
    def from_metadata(cls, metadata: Mapping[str, Any]) -> AutoPolicy:
        """The policy chosen in training (``metadata["auto"]``), else the default."""
        auto = metadata.get("auto") or {}
        return cls(float(auto.get("max_series_interval_decades", DEFAULT_SERIES_INTERVAL_DECADES)))

    def accepts(self, series: Estimate | None, frames: int) -> bool:
        """Whether ``series``, fitted over ``frames`` distinct frames, answers instead of the model."""
        return (series is not None and series.state == "ok" and frames >= MIN_SERIES_FRAMES
                and interval_decades(series) <= self.max_series_interval_decades)


class HybridEstimator:
    """Estimate E from grasp records with a trained model (``hybrid``/``cnn``) or ``auto``.

    Parameters
    ----------
    predictor : CompliancePredictor
    settings : Settings
    calibration, marker_calibration : Calibration, path or None
        Calibrations of the estimator's finger (of records: a stream has its own) and (for a
        marker variant) the other finger; None reads the file each record's sensor names.
    policy : AutoPolicy or None
        ``auto``'s rule; None takes the model's (:meth:`AutoPolicy.from_metadata`).

    Raises
    ------
    ModelError
        The model was trained on depth measured with another ``estimator.depth_binning``
        than the settings'.
    """

    def __init__(self, predictor: CompliancePredictor, *, settings: Settings,
                 calibration: Calibration | str | Path | None = None,
                 marker_calibration: Calibration | str | Path | None = None,
                 policy: AutoPolicy | None = None):
        if predictor.depth_binning != estimator_settings(settings).depth_binning:
            raise ModelError(
                f"model {predictor.model_dir} was trained on depth binned by {predictor.depth_binning} "
                f"(data.depth_binning in its metadata); the settings measure with estimator.depth_binning = "
                f"{estimator_settings(settings).depth_binning}: set that to {predictor.depth_binning} or retrain the model")
        self.predictor = predictor
        self.settings = settings
        self.calibration = calibration
        self.marker_calibration = marker_calibration
        self.policy = AutoPolicy.from_metadata(predictor.metadata.raw) if policy is None else policy

    @property
    def method(self) -> str:
        return self.predictor.variant.method

    def _smoothing_refusal(self, sampled: SampledGrasp) -> str:
        """Why the model cannot read ``sampled``'s depth (empty when it can): its calibration smooths the
        colours otherwise than the calibrations of the model's training data, so shallow slopes read
        otherwise than the model learned."""
        used = None if sampled.measurements is None else sampled.measurements.calibration_smoothing_px
        trained = self.predictor.calibration_smoothing_px
        if used is None or used in trained:  # as check_dataset_fits compares them
            return ""
        return (f"it smooths the colours by {used:g} px, the model was trained on depth from calibrations smoothing "
                f"by {smoothings_text(trained)}: calibrate with `estimator calibrate --smoothing-px {trained[0]:g}`")

    def sample(self, record: GraspRecord) -> SampledGrasp:
        """The model's view of ``record`` (:func:`~estimator.inference.sampling.sample_grasp`)."""
        return self._sample(self._stream(record))

    def _stream(self, record: GraspRecord) -> GraspStream:
        return record_stream(record, settings=self.settings, calibration=self.calibration)

    def _sample(self, stream: GraspStream) -> SampledGrasp:
        variant = self.predictor.variant
        return sample_stream(stream, n_frames=variant.n_frames, size_px=variant.size_px, rgb=variant.image == "rgb",
                             markers=variant.markers, marker_calibration=self.marker_calibration,
                             window_m=variant.window_m)

    def estimate(self, record: GraspRecord, *, mode: str = "model") -> Estimate:
        """Young's modulus of the object grasped in ``record``, stamped with its latency: the record
        fed through a :class:`~estimator.stream.GraspStream` (:func:`~estimator.inference.sampling.record_stream`),
        then :meth:`estimate_stream`.

        Parameters
        ----------
        record : GraspRecord
        mode : {"model", "auto"}

        Returns
        -------
        Estimate
            Never NaN, infinite or negative; a refusal carries its reason.
        """
        return self.estimate_stream(self._stream(record), mode=mode)

    def estimate_stream(self, stream: GraspStream, *, mode: str = "model") -> Estimate:
        """Young's modulus of the object grasped in what ``stream`` has received (live: the
        estimator service's stream; offline: a record's), stamped with its latency.

        The model's view of the grasp (:func:`~estimator.inference.sampling.sample_stream`) from the
        stream's finger and calibration, and the other finger's for a marker variant; a grasp that
        cannot be sampled gets a refusal with its reason (in ``auto`` mode saying what the
        force/width-only ``no_tactile`` fit reads over the stream's measurements, unless the force
        and width give no loading phase: that reason alone).

        Parameters
        ----------
        stream : GraspStream
        mode : {"model", "auto"}

        Returns
        -------
        Estimate
            Never NaN, infinite or negative; a refusal carries its reason.
        """
        started = time.perf_counter()
        _check_mode(mode)
        sampled = self._sample(stream)
        if not sampled and mode == "auto":
            fallback = estimate_measurements(stream.measurements(tactile=False), "no_tactile")
            if not fallback and not stream.segment():  # the force and width fail, whatever the frames
                result = Estimate.refuse("auto", fallback.reason)
            else:
                why = "" if sampled.reason in fallback.reason else f" ({sampled.reason})"  # said once
                result = _as_fallback(fallback, f"no tactile sample{why}: force and width only")
        else:
            result = self.estimate_sampled(sampled, mode=mode)
        return result.with_latency(time.perf_counter() - started)

    def estimate_sampled(self, sampled: SampledGrasp, *, mode: str = "model") -> Estimate:
        """The estimate from an already sampled grasp (see :meth:`estimate`)."""
        _check_mode(mode)
        method = "auto" if mode == "auto" else self.method
        if not sampled:
            return Estimate.refuse(method, sampled.reason)
        by_method = {e.method: e for e in sampled.estimates}
        series = by_method.get("series")
        if mode == "auto" and self.policy.accepts(series, distinct_frames(sampled.force_n)):
            return _as("auto", series, f"series interval {interval_decades(series):.2f} <= "
                                       f"{self.policy.max_series_interval_decades:g} decades, model skipped")
        fit = sampled_input_range(sampled, self.predictor.variant)
        if not fit:
            return _without_model(method, mode, by_method, f"the model does not apply to this sensor: {fit.refusal}")
        smoothing = self._smoothing_refusal(sampled)
        if smoothing:
            return _without_model(method, mode, by_method, f"the model does not apply to this calibration: {smoothing}")
        rig = rig_notes(sampled, self.predictor.rig_range)
        if rig:
            fit = replace(fit, notes=(*fit.notes, *rig), widen=fit.widen * RIG_WIDENING)
        try:
            probs = self.predictor.predict_distribution([sampled])[0]
        except ModelError as exc:
            # A served model that fails on live grasps (yet passed its reference grasp) must be heard of.
            log.warning("the model gives no estimate (%s); %s", exc,
                        "an analytical estimate answers" if mode == "auto" else "refused")
            return _without_model(method, mode, by_method, f"the model gives no estimate: {exc}")
        peak_force_n = float(np.max(sampled.force_n))
        said = self.predictor.describe(probs, limit_pa=self.settings.resolution_limit_pa, peak_force_n=peak_force_n,
                                       widen=fit.widen, gel_scale=gel_scale(sampled.gel_modulus_pa))
        calibrated = (f"{self.predictor.interval_level:.0%} interval calibrated on validation objects' grasps "
                      f"{self.predictor.metadata.force_band_at(peak_force_n)}")
        states = ", ".join(f"{e.method} {e.state}" for e in sampled.estimates)
        model = f"{self.predictor.variant.name} model over {self.predictor.variant.n_frames} frames"
        p_rigid = self.predictor.metadata.p_rigid_at(peak_force_n)
        if said.state == "lower_bound" and said.p_above_limit >= p_rigid:
            what = (f"P(E >= the sensor's resolution limit) = {said.p_above_limit:.2f} >= {p_rigid:g}: stiffer "
                    "objects look alike to the gel")
        elif said.state == "lower_bound":
            what = (f"the {calibrated} lies wholly above the sensor's resolution limit (P(E >= it) = "
                    f"{said.p_above_limit:.2f} < {p_rigid:g}): stiffer objects look alike to the gel")
        elif said.state == "upper_bound":
            what = "median at or below the softest training label"
        elif fit.notes:
            what = (f"{calibrated}, widened {fit.widen:g} times as the grasp lies outside what the model was "
                    "trained on (its coverage there is not validated)")
        else:
            what = calibrated
        floor_log10, floor_method = self.predictor.floor(sampled)
        if floor_method is not None:
            what += _floor_said(said, floor_method, 10.0 ** floor_log10 / gel_scale(sampled.gel_modulus_pa),
                                self.predictor.metadata.floor_leak)
        if fit.notes:
            what += "; outside the training range: " + "; ".join(fit.notes)
        reason = f"{model}; {what}; analytical inputs: {states}"
        segment = getattr(sampled.measurements, "segment", None)  # its flags and loading phase, as the fits say
        said_of_data = segment.describe() if segment is not None else ""
        if said_of_data:
            reason += f"; {said_of_data}"
        if mode == "auto":
            reason = "model: " + reason
        return Estimate(method, said.e_pa, (said.low_pa, said.high_pa), said.state, reason)


def _floor_said(said: Described, method: str, floor_pa: float, leak: float) -> str:
    """What the reason says of the analytical floor ``floor_pa`` (Pa, the measuring gel's) of ``method``.

    The floor is soft: it weights the distribution's mass below it by ``leak`` (the share of such bounds
    that fail), while the interval is calibrated about the median (:func:`~estimator.inference.distribution.describe`)
    and is not cut at the floor: cutting it would drop the truth on the grasps whose bound fails (a foam
    earplug grasped fast, another contact model), below the stated level. So the reason says the
    distribution was floored there only where the interval lies at or above the floor, and otherwise
    says the bound was weighed and that the interval or the answer reaches below it.
    """
    weighted = f"; the {method} lower bound {floor_pa:.3g} Pa weighted the distribution's mass below it by the floor's leak {leak:g}"
    if said.state != "lower_bound" and said.e_pa < floor_pa:
        # A model sure enough stays below it.
        return f"{weighted}, yet the answer lies below that bound: the model's reading outweighs it"
    # Said to 3 digits: a floor that rounds up past the interval's low end is not said to hold there.
    if said.low_pa is not None and said.low_pa >= float(f"{floor_pa:.3g}"):
        return f"; its distribution floored at the {method} lower bound {floor_pa:.3g} Pa"
    if said.state == "lower_bound":  # a floor above the resolution limit: no number above it is offered
        return f"{weighted}; it lies above the sensor's resolution limit, where the bound is stated"
    if said.low_pa is None:
        return f"{weighted}; the interval is open below, as an {said.state.replace('_', ' ')} is"
    return (f"{weighted}; the interval, calibrated about the median, still reaches below that bound (to "
            f"{said.low_pa:.3g} Pa): such bounds fail on some grasps, so it is not cut there")


def _check_mode(mode: str) -> None:
    if mode not in MODES:
        raise ModelError(f"mode {mode!r}: expected one of {', '.join(MODES)}")


def _without_model(method: str, mode: str, by_method: Mapping[str, Estimate], why: str) -> Estimate:
    """A refusal saying ``why`` the model gives no answer; in ``auto`` mode the first analytical
    estimate of :data:`FALLBACK_ORDER` that is not a refusal, relabelled, when there is one."""
    if mode != "auto":
        return Estimate.refuse(method, why)
    fallback = next((by_method[m] for m in FALLBACK_ORDER if by_method.get(m)), None)
    if fallback is None:
        return Estimate.refuse(method, f"{why}; and every analytical method refuses")
    return _as_fallback(fallback, why)


def _as_fallback(estimate: Estimate, why: str) -> Estimate:
    """An analytical ``estimate`` as ``auto``'s answer, except ``no_tactile``'s: force and width alone
    cannot tell a soft object from a rigid one pressed into the gel (a steel ball reads 0.3-0.5 MPa
    on the nominal rig, ``ok``), so its reading is said in a refusal, never rendered."""
    answer = _as("auto", estimate, why)
    if estimate.method != "no_tactile" or not estimate:
        return answer
    return Estimate.refuse("auto", f"{answer.reason}; not rendered: force and width alone read a rigid "
                                   f"object pressed into the gel as soft (it reads {estimate.e_pa:.3g} Pa)")


def _as(method: str, estimate: Estimate, why: str) -> Estimate:
    """``estimate`` relabelled as ``method``, its reason prefixed with which answer it is and why."""
    reason = f"{estimate.method}: {why}" + (f"; {estimate.reason}" if estimate.reason else "")
    return Estimate(method, estimate.e_pa, estimate.interval_pa, estimate.state, reason)
