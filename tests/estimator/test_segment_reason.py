"""Why a grasp's frames cannot be used is said once: in ``Segment.frame_reason``, which a tactile
method's refusal states before the segmentation's notes (``Segment.describe``)."""

from __future__ import annotations

import dataclasses

import numpy as np

from estimator.segment import segment_grasp
from estimator.stream import GraspStream

WHY = "no tactile frame within the loading phase"


def test_frames_outside_the_loading_phase_are_flagged_and_said_in_frame_reason_only():
    tf = np.arange(0.0, 1.2, 1 / 80)
    force = 20.0 * np.clip((tf - 0.5) / 0.3, 0, 1) ** 1.5
    tw = np.arange(0.003, 1.2, 1 / 10)
    frames = np.arange(0.011, 0.4, 1 / 30)  # all before contact
    segment = segment_grasp(tf, force, tw, 0.06 - 0.0375 * np.minimum(tw, 0.8), frames,
                            contact_force_n=0.75, n_frames=5)
    assert segment and segment.frame_reason.startswith(WHY) and "too_few_samples" in segment.flags
    assert WHY not in segment.describe()


def test_a_refusal_for_frames_outside_the_loading_phase_says_why_once(settings, records):
    record = records["stress_ball"]
    streams = []
    for s in record.frames:  # the frames stamped at two times: before contact and after the hold
        t = np.where(np.arange(s.t_s.size) < s.t_s.size // 2, s.t_s[0], s.t_s[-1])
        streams.append(dataclasses.replace(s, t_s=t))
    stream = GraspStream.from_record(dataclasses.replace(record, frames=tuple(streams)), settings=settings,
                                     calibration=None, methods=("series",))
    (estimate,) = stream.estimate().estimates
    assert estimate.state == "insufficient_data" and estimate.reason.count(WHY) == 1, estimate.reason
