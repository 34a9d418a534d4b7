"""Object geometry of the grasp simulator (teleop.sim.shapes)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from teleop.catalogue import ObjectSpec, load_catalogue
from teleop.errors import SimulationError
from teleop.settings import load_settings
from teleop.sim.contact import NO_CONTACT_GAP_M
from teleop.sim.grasp import contact_grid
from teleop.sim.shapes import (
    FIT_MARGIN,
    OFFSET_FRACTION,
    Pose,
    draw_pose,
    make_scene,
    object_size,
    object_texture,
    scaled_size,
    surface_distance,
)

CELL = 4.0 / 11.0 * 1e-3
GRID = (63, 88)
PAD = (250 / 11 * 1e-3, 350 / 11 * 1e-3)
SMOOTH = 1e-12  # texture amplitude small enough to ignore


def spec(shape: str, size=None, name=None, texture=SMOOTH, material="metal") -> ObjectSpec:
    return ObjectSpec(name=name or f"test_{shape}", shape=shape, material=material, modulus_pa=1e9,
                      size_m=size, texture_m=texture)


def scene(obj: ObjectSpec, rotation=None, offset=(0.0, 0.0), seed=0):
    pose = Pose(rotation=np.eye(3) if rotation is None else rotation, offset_m=offset)
    return make_scene(obj, pose, shape=GRID, cell_m=(CELL, CELL), fingers=("left", "right"),
                      rng=np.random.default_rng(seed))


def grid_radius() -> np.ndarray:
    rows, cols = np.indices(GRID)
    return np.hypot((rows - (GRID[0] - 1) / 2) * CELL, (cols - (GRID[1] - 1) / 2) * CELL)


def test_sphere_gap_is_the_spherical_cap_on_both_fingers():
    radius = 0.01
    result = scene(spec("sphere", (2 * radius,) * 3))
    r = grid_radius()
    cap = radius - np.sqrt(np.clip(radius**2 - r**2, 0.0, None))
    inside = r < 0.95 * radius
    for finger in ("left", "right"):
        gap = result.gap_m[finger]
        # The grid has no ray through the pole: the gap is measured from the nearest ray (< 2 um lower).
        np.testing.assert_allclose(gap[inside], cap[inside] - cap.min(), atol=2e-6)
        assert (gap[r > 1.01 * radius] == NO_CONTACT_GAP_M).all()
    assert result.extent_m == pytest.approx(2 * radius, abs=5e-6)
    assert result.cross_section_m2 == pytest.approx(2 / 3 * math.pi * radius**2, rel=0.05)


def test_box_extent_cross_section_and_an_object_larger_than_the_pad():
    size = (0.03, 0.06, 0.05)  # the face (y, z) is larger than the 32 x 23 mm pad
    result = scene(spec("box", size))
    assert result.extent_m == pytest.approx(size[0], abs=1e-6)
    assert result.cross_section_m2 == pytest.approx(size[1] * size[2], rel=0.05)
    for gap in result.gap_m.values():
        assert (gap < NO_CONTACT_GAP_M).all()  # the face covers the whole pad
        assert gap.max() < 1e-6  # and it is flat


def test_tilted_box_meets_the_gel_on_an_edge():
    tilt = Rotation.from_rotvec([0.0, 0.0, math.radians(5.0)]).as_matrix()  # about z: the face slopes along y
    gap = scene(spec("box", (0.03, 0.06, 0.05)), rotation=tilt).gap_m["left"]
    slope = np.diff(gap.mean(axis=0)) / CELL
    assert np.allclose(slope, slope.mean(), rtol=0.02) and abs(slope.mean()) == pytest.approx(math.tan(math.radians(5)), rel=0.02)
    assert gap[:, 0].max() < 1e-6 or gap[:, -1].max() < 1e-6  # first contact along one pad edge


def test_cylinder_side_on_gives_a_line_contact_at_its_angle():
    angle = math.radians(30.0)
    # Body z (the axis) into world y, then rotate about the squeeze axis by 30 degrees.
    rotation = (Rotation.from_rotvec([angle, 0.0, 0.0]) * Rotation.from_rotvec([math.pi / 2, 0.0, 0.0])).as_matrix()
    gap = scene(spec("cylinder", (0.012, 0.012, 0.08)), rotation=rotation).gap_m["left"]
    assert gap.min(axis=0).max() < 5e-6  # every column touches the line of first contact
    line_rows = np.argmin(gap, axis=0)
    direction = np.polyfit(np.arange(GRID[1]) * CELL, -line_rows * CELL, 1)[0]  # rows run down, world z up
    assert math.degrees(math.atan(direction)) == pytest.approx(30.0, abs=1.0)


def test_cylinder_end_on_is_a_flat_punch_with_rounded_edge():
    rotation = Rotation.from_rotvec([0.0, math.pi / 2, 0.0]).as_matrix()  # body z onto world x
    result = scene(spec("cylinder", (0.012, 0.012, 0.03)), rotation=rotation)
    gap = result.gap_m["left"]
    r = grid_radius()
    assert result.extent_m == pytest.approx(0.03, abs=1e-6)
    assert gap[r < 0.004].max() < 1e-7  # the flat end
    rim = (r > 0.0055) & (r < 0.0059)
    assert gap[rim].min() > 1e-6 and gap[rim].max() < 1.2e-3  # rounded, not a step
    assert (gap[r > 0.0062] == NO_CONTACT_GAP_M).all()


def test_hex_prism_flats_face_the_fingers():
    result = scene(spec("hex_prism", (0.013, 0.013 * 2 / math.sqrt(3), 0.02)))
    assert result.extent_m == pytest.approx(0.013, abs=1e-6)
    rotated = scene(spec("hex_prism", (0.013, 0.013 * 2 / math.sqrt(3), 0.02)),
                    rotation=Rotation.from_rotvec([0.0, 0.0, math.pi / 2]).as_matrix())
    assert rotated.extent_m == pytest.approx(0.013 * 2 / math.sqrt(3), abs=0.002)  # corners toward the fingers


def test_irregular_objects_are_non_convex_and_not_axisymmetric():
    rng = np.random.default_rng(0)
    size = (0.03, 0.035, 0.04)
    for k in range(5):
        obj = spec("irregular", size, name=f"blob_{k}")
        distance = surface_distance(obj, size)
        # Surface points along random directions (bisection on the inside test), pulled in a hair.
        directions = rng.normal(size=(1000, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        lo, hi = np.zeros(1000), np.full(1000, float(np.linalg.norm(size)))
        for _ in range(40):
            mid = (lo + hi) / 2
            inside = distance(directions * mid[:, None]) < 0
            lo, hi = np.where(inside, mid, lo), np.where(inside, hi, mid)
        surface = directions * (0.999 * lo)[:, None]
        # Convex: the midpoint of every chord is inside. Over a dent, chords pass outside.
        i, j = np.triu_indices(1000, 1)
        near = np.einsum("ij,ij->i", directions[i], directions[j]) > math.cos(0.6)
        assert (distance((surface[i[near]] + surface[j[near]]) / 2) > 1e-5).any(), obj.name
        points = rng.uniform(-0.5, 0.5, (40000, 3)) * np.asarray(size)
        # Not a body of revolution about any axis: its three extents differ and a sideways turn changes it.
        turned = distance(points @ Rotation.from_rotvec([0.0, 0.0, 1.0]).as_matrix().T)
        assert ((turned < 0) != (distance(points) < 0)).mean() > 0.02
        if k < 2:
            result = scene(obj)
            assert not np.allclose(result.gap_m["left"], np.fliplr(result.gap_m["right"]))  # the sides differ


def test_texture_has_the_requested_roughness():
    result = scene(spec("box", (0.03, 0.06, 0.05), texture=20e-6), seed=3)
    gap = result.gap_m["left"]
    assert gap.min() == 0.0
    assert np.std(gap) == pytest.approx(20e-6, rel=0.15)
    assert object_texture(spec("box", texture=0.0, material="foam")) > object_texture(spec("box", texture=0.0))


def test_unknown_sizes_are_fixed_by_the_name_and_fit_the_gripper(object_table):
    objects = load_catalogue(object_table)
    assert object_size(objects[0]) == object_size(objects[0])
    rng = np.random.default_rng(0)
    for k, obj in enumerate(objects):
        size = object_size(obj)
        assert all(0.004 < s < 0.2 for s in size), (obj.name, size)
        pose = draw_pose(obj, size, rng=rng, max_width_m=0.08, pad_m=PAD)
        assert np.allclose(pose.rotation @ pose.rotation.T, np.eye(3))
        if k % 15 == 0:  # the ray-cast extent agrees: the object fits
            assert make_scene(obj, pose, shape=(16, 22), cell_m=(4 * CELL, 4 * CELL), fingers=("l", "r"),
                              rng=rng).extent_m < 0.08
        assert all(abs(o) <= 0.2 * p for o, p in zip(pose.offset_m, (PAD[1], PAD[0]), strict=True))
    sizes = {obj.shape: object_size(obj) for obj in objects}
    assert sizes["box"] != sizes["irregular"]


def test_poses_vary_between_grasps_and_repeat_with_the_seed():
    obj = spec("box", (0.03, 0.05, 0.04))
    size = object_size(obj)
    draws = [draw_pose(obj, size, rng=np.random.default_rng(s), max_width_m=0.08, pad_m=PAD) for s in (1, 1, 2)]
    np.testing.assert_array_equal(draws[0].rotation, draws[1].rotation)
    assert not np.allclose(draws[0].rotation, draws[2].rotation)


def test_an_object_too_wide_for_the_gripper_is_refused():
    obj = spec("sphere", (0.09,) * 3)
    with pytest.raises(SimulationError, match="does not fit"):
        draw_pose(obj, object_size(obj), rng=np.random.default_rng(0), max_width_m=0.08, pad_m=PAD)


def test_an_object_beside_the_pads_is_refused():
    with pytest.raises(SimulationError, match="does not face the pads"):
        scene(spec("sphere", (0.01,) * 3), offset=(0.05, 0.0))


def test_a_scaled_size_keeps_the_shape_and_fits_the_gripper():
    factors = (1.1, 0.9, 1.2)
    assert scaled_size(spec("sphere", (0.02,) * 3), (0.02,) * 3, factors, max_width_m=0.08) == pytest.approx(
        (0.022,) * 3)  # still a sphere
    cylinder = spec("cylinder", (0.02, 0.02, 0.05))
    assert scaled_size(cylinder, cylinder.size_m, factors, max_width_m=0.08) == pytest.approx((0.022, 0.022, 0.06))
    box = spec("box", (0.02, 0.03, 0.04))
    assert scaled_size(box, box.size_m, factors, max_width_m=0.08) == pytest.approx((0.022, 0.027, 0.048))
    # Grown past what the gripper takes: shrunk back as a whole, to the margin or to what it was.
    ball = spec("sphere", (0.07,) * 3)
    grown = scaled_size(ball, ball.size_m, (1.2, 1.2, 1.2), max_width_m=0.08)
    assert len(set(grown)) == 1 and grown[0] == pytest.approx(0.95**2 * 0.08, rel=0.01)  # the hull's width
    draw_pose(ball, grown, rng=np.random.default_rng(0), max_width_m=0.08, pad_m=PAD)
    wide = spec("box", (0.075, 0.09, 0.09))
    kept = scaled_size(wide, wide.size_m, (1.2, 1.1, 0.9), max_width_m=0.08)
    assert min(kept) == pytest.approx(0.075) and kept[1] / kept[0] == pytest.approx(1.1 / 1.2 * 0.09 / 0.075)
    shrunk = scaled_size(wide, wide.size_m, (0.8, 0.8, 0.8), max_width_m=0.08)
    assert shrunk == pytest.approx((0.06, 0.072, 0.072))  # shrinking is never limited


def test_a_box_that_fits_only_without_the_margin_is_refused():
    """Poses keep FIT_MARGIN: a cube 97 % of the opening across (every face) fits no drawn pose, and the
    refusal names the margin; one at 90 % is posed within it."""
    width = 0.08
    pad = (0.02, 0.025)
    tight = ObjectSpec(name="tight cube", shape="box", material="wood", modulus_pa=1e9, size_m=(0.97 * width,) * 3)
    with pytest.raises(SimulationError, match="does not fit between fingers"):
        draw_pose(tight, tight.size_m, rng=np.random.default_rng(0), max_width_m=width, pad_m=pad)
    roomy = ObjectSpec(name="roomy cube", shape="box", material="wood", modulus_pa=1e9, size_m=(0.9 * width,) * 3)
    pose = draw_pose(roomy, roomy.size_m, rng=np.random.default_rng(0), max_width_m=width, pad_m=pad)
    corners = np.array(np.meshgrid(*[(-s / 2, s / 2) for s in roomy.size_m])).reshape(3, -1).T
    assert np.ptp(corners @ pose.rotation[0]) < FIT_MARGIN * width


def test_the_contact_offset_stays_in_the_central_part_of_each_pad_axis():
    """draw_pose offsets the object by up to OFFSET_FRACTION (a fifth) of the pad along each pad axis: y
    (offset_m[0]) within the pad's width pad_m[1], z within its height pad_m[0]. Further out, contacts would
    sit on the pad's rim, where the gel is clamped."""
    assert OFFSET_FRACTION == 0.2
    ball = ObjectSpec(name="ball", shape="sphere", material="rubber", modulus_pa=1e6, size_m=(0.02,) * 3)
    pad = (0.01, 0.04)  # (height, width): a wide, low pad
    rng = np.random.default_rng(0)
    offsets = np.array([draw_pose(ball, ball.size_m, rng=rng, max_width_m=0.08, pad_m=pad).offset_m
                        for _ in range(200)])
    assert np.abs(offsets[:, 0]).max() <= OFFSET_FRACTION * pad[1]
    assert np.abs(offsets[:, 1]).max() <= OFFSET_FRACTION * pad[0]
    assert np.abs(offsets[:, 0]).max() > 0.8 * OFFSET_FRACTION * pad[1]  # the width's range is used


def test_an_unsized_hex_prism_is_drawn_regular():
    """A hex prism the catalogue gives no size: across corners is 2 / sqrt(3) of across flats (a regular
    hexagon), as a sized one's must be."""
    prism = ObjectSpec(name="unsized nut", shape="hex_prism", material="metal", modulus_pa=2e11, size_m=None)
    flats, corners, length = object_size(prism)
    assert corners == pytest.approx(flats * 2 / math.sqrt(3), rel=1e-12)
    assert object_size(prism) == (flats, corners, length)  # fixed by the name


def test_the_bulk_cross_section_is_the_whole_objects_not_the_pads_chord():
    """A 6 cm ball met off its centre by the pads: its bulk cross-section is volume / its own extent
    (pi D^2 / 6), not volume over the shorter chord between the first-contact points."""
    sensor = load_settings().sensors[0]
    shape, cell = contact_grid(sensor, 8)
    ball = ObjectSpec(name="big ball", shape="sphere", material="rubber", modulus_pa=1e6, size_m=(0.06,) * 3)
    scene = make_scene(ball, Pose(rotation=np.eye(3), offset_m=(0.0, 0.022)), shape=shape, cell_m=cell,
                       fingers=("left", "right"), rng=np.random.default_rng(0), size=ball.size_m)
    assert scene.extent_m < 0.057  # the pads meet a chord, not the diameter
    assert scene.cross_section_m2 == pytest.approx(math.pi * 0.06**2 / 6, rel=0.03)


def test_the_right_finger_sees_the_pad_mirrored():
    """The right sensor's image columns run along -y: a ball offset along +y touches the left gel right of
    its centre column and the right gel left of it (mirror images), the frames the estimator reads."""
    shape, cell = contact_grid(load_settings().sensors[0], 8)
    ball = ObjectSpec(name="ball", shape="sphere", material="rubber", modulus_pa=1e6, size_m=(0.02,) * 3,
                      texture_m=1e-9)
    scene = make_scene(ball, Pose(rotation=np.eye(3), offset_m=(0.003, 0.0)), shape=shape, cell_m=cell,
                       fingers=("left", "right"), rng=np.random.default_rng(0), size=ball.size_m)
    (_, left_col), (_, right_col) = scene.first_contact_rc["left"], scene.first_contact_rc["right"]
    centre = (shape[1] - 1) / 2
    assert left_col > centre + 1 and right_col < centre - 1
    assert abs(left_col - (shape[1] - 1 - right_col)) <= 1
    np.testing.assert_allclose(scene.gap_m["right"], np.fliplr(scene.gap_m["left"]), atol=2e-6)


def test_a_small_box_keeps_its_corners_rounded_only_a_little():
    """Edges are rounded by EDGE_RADIUS_M capped at 15 % of the smallest side: a 2 mm die stays a box (its
    near-corner points are inside), not a 1 mm-radius ball."""
    die = ObjectSpec(name="die", shape="box", material="plastic", modulus_pa=2e9, size_m=(0.002,) * 3)
    distance = surface_distance(die, die.size_m)
    inside_corner = np.array([[0.0008, 0.0008, 0.0008]])
    face = np.array([[0.001, 0.0, 0.0]])
    assert float(distance(inside_corner)[0]) < 0
    assert float(distance(face)[0]) == pytest.approx(0.0, abs=1e-12)
