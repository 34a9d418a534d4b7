"""``auto`` mode's refusal of a grasp it cannot sample: the force and width's own reason when they give
no loading phase, what force and width alone read when only the tactile frames are missing."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from estimator.settings import estimator_settings
from estimator.stream import GraspStream


@pytest.fixture(scope="module")
def shipped_model():
    from estimator.inference.infer import CompliancePredictor, default_model_dir

    return CompliancePredictor(default_model_dir())


def hybrid(model, settings, calibration):
    from estimator.inference.hybrid import HybridEstimator

    return HybridEstimator(model, settings=settings, calibration=calibration)


@pytest.mark.slow
def test_a_grasp_without_contact_is_refused_for_its_force_not_its_frames(shipped_model, settings, calibration,
                                                                          records):
    record = records["stress_ball"]
    peak_n = float(np.max(record.force_n.value))
    strict = dataclasses.replace(settings, gripper=dataclasses.replace(settings.gripper, target_force_n=4 * peak_n))
    strict = strict.with_section(dataclasses.replace(estimator_settings(strict), contact_force_n=2 * peak_n))
    segment = GraspStream.from_record(record, settings=strict, calibration=calibration).segment()
    assert not segment and segment.reason.startswith("no contact")
    assert len(record.stream(settings.sensing.finger).t_s) > 0  # the frames are there
    said = hybrid(shipped_model, strict, calibration).estimate(record, mode="auto")
    assert (said.method, said.state, said.reason) == ("auto", "insufficient_data", segment.reason)
    assert said.e_pa is None


@pytest.mark.slow
def test_a_grasp_whose_frames_are_missing_says_what_force_and_width_read(shipped_model, settings, calibration,
                                                                         records):
    record = records["stress_ball"]
    finger = settings.sensing.finger
    stream = GraspStream.from_record(record, settings=settings, calibration=calibration)
    assert stream.segment()  # the force and width give a loading phase
    lost = dataclasses.replace(record, frames=tuple(dataclasses.replace(s, t_s=s.t_s[:1], encoded=s.encoded[:1])
                                                    if s.finger == finger else s for s in record.frames))
    said = hybrid(shipped_model, settings, calibration).estimate(lost, mode="auto")
    assert not said and said.method == "auto"
    assert said.reason.startswith("no_tactile: no tactile sample") and "force and width only" in said.reason
