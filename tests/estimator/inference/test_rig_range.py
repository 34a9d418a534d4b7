"""The model's rig-range check (``rig_notes``): the documented range's own ends lie inside, though the
shipped model records the drawn rigs' extremes a fraction of a percent within them."""

from __future__ import annotations

import json
from types import SimpleNamespace

from estimator.inference.hybrid import rig_notes
from estimator.inference.infer import default_model_dir


def shipped_rig_range() -> dict:
    return json.loads((default_model_dir() / "metadata.json").read_text())["data"]["rig_range"]


def rig(gel_modulus_pa, gel_thickness_m, finger_stiffness_n_per_m=1e5):
    return SimpleNamespace(gel_modulus_pa=gel_modulus_pa, gel_thickness_m=gel_thickness_m,
                           finger_stiffness_n_per_m=finger_stiffness_n_per_m)


def test_the_documented_ends_of_the_shipped_range_lie_inside():
    rig_range = shipped_rig_range()
    assert rig_range["gel_modulus_pa"][0] > 120e3 and rig_range["gel_thickness_m"][1] < 4.5e-3  # as shipped
    for gel in ((120e3, 4.5e-3), (400e3, 2.5e-3)):
        assert rig_notes(rig(*gel), rig_range) == ()


def test_a_rig_clearly_outside_is_named_with_digits_that_do_not_contradict():
    rig_range = {"gel_modulus_pa": [120038.8, 399847.5], "gel_thickness_m": [0.0025005, 0.0044992]}
    notes = rig_notes(rig(100e3, 5e-3), rig_range)
    assert len(notes) == 2
    assert notes[0].startswith("gel modulus 100 kPa outside the 120-399.8 kPa trained on")
    assert notes[1].startswith("gel thickness 5 mm outside the 2.501-4.499 mm trained on")
