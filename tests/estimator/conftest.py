"""Fixtures of the estimator tests: tiny synthetic datasets, simulated records, a calibration (the
learned model's), and a soft and a rigid grasp with an estimator service to send them to (the live ones)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from support.live import Rig

from estimator.estimate import Estimate
from estimator.inference.inputs import MEASUREMENT_VERSION
from estimator.inference.provenance import SPLITS
from estimator.measure import measure_grasp
from estimator.measurements import GraspMeasurements
from estimator.settings import estimator_settings
from estimator.training.dataset import DATASET_FORMAT, split_objects
from estimator.training.samples import TrainingSample, save_sample
from teleop.catalogue import load_catalogue
from teleop.record import GraspRecord, read_record
from teleop.settings import CONFIG_DIR, load_settings
from teleop.sim.grasp import simulate_grasp

SIZE = (16, 22)
N_FRAMES = 3
# name -> (material, modulus): soft to rigid, two objects per material so every split gets some.
OBJECTS = {
    "foam_a": ("foam", 2e4), "foam_b": ("foam", 6e4), "foam_c": ("foam", 1e4),
    "rubber_a": ("rubber", 5e5), "rubber_b": ("rubber", 2e6), "rubber_c": ("rubber", 1e6),
    "plastic_a": ("plastic", 2e9), "plastic_b": ("plastic", 3e9), "plastic_c": ("plastic", 1e9),
    "metal_a": ("metal", 2e11), "metal_b": ("metal", 7e10), "metal_c": ("metal", 1e11),
}


def synthetic_sample(name: str, grasp: int, augmentation: int, *, rng: np.random.Generator,
                     markers: bool = False, size: tuple[int, int] = SIZE) -> TrainingSample:
    """A sample whose contact depth and series estimate carry its modulus (so a model can learn it)."""
    material, modulus = OBJECTS[name]
    stiffness = (np.log10(modulus) - 3.0) / 9.0  # 0 soft .. 1 rigid
    rows, cols = np.indices(size)
    blob = np.exp(-((rows - size[0] / 2) ** 2 + (cols - size[1] / 2) ** 2) / (2.0 * (2 + 4 * (1 - stiffness)) ** 2))
    ramp = np.linspace(0.3, 1.0, N_FRAMES)[:, None, None]
    depth = (ramp * blob * 1e-3 * (0.2 + stiffness) + rng.normal(0, 2e-5, (N_FRAMES, *size))).astype(np.float32)
    rgb = (depth[..., None] * np.array([40e3, -20e3, 10e3])).astype(np.float32)
    e_series = modulus * 10 ** rng.normal(0, 0.3)
    estimates = (
        Estimate.ok("series", e_series, e_series / 2, e_series * 2, "synthetic"),
        Estimate.at_least("hertz", 1e6, "synthetic bound") if stiffness > 0.5 else Estimate.refuse("hertz", "none"),
        Estimate.refuse("elastic", "synthetic refusal"),
        Estimate.at_most("no_tactile", 5e5, "synthetic bound"),
    )
    extra = {}
    if markers:
        extra = {"rgb_diff_markers": rgb[:, ::-1].copy(), "depth_markers_m": depth[:, ::-1].copy()}
    return TrainingSample(
        object_name=name, grasp=grasp, augmentation=augmentation, rgb_diff=rgb, depth_m=depth,
        force_n=np.linspace(1.0, 20.0, N_FRAMES), width_m=np.linspace(0.05, 0.049, N_FRAMES),
        label_modulus_pa=modulus, material=material, shape="sphere", estimates=estimates, **extra,
    )


def write_synthetic_dataset(out: Path, *, grasps: int = 2, shifts: int = 2, markers: bool = False,
                            seed: int = 0) -> Path:
    """A build-dataset directory of synthetic samples (same layout, split and manifest keys)."""
    split = split_objects({n: m for n, (m, _) in OBJECTS.items()}, seed=seed, fractions=(0.5, 0.25, 0.25))
    rng = np.random.default_rng(seed)
    counts = dict.fromkeys(SPLITS, 0)
    for name_split, names in split.items():
        for name in names:
            for grasp in range(grasps):
                for shift in range(shifts):
                    path = out / name_split / name / f"{name}_g{grasp}_a{shift}.npz"
                    path.parent.mkdir(parents=True, exist_ok=True)
                    save_sample(synthetic_sample(name, grasp, shift, rng=rng, markers=markers), path)
                    counts[name_split] += 1
    (out / "split.json").write_text(json.dumps({"seed": seed, "fractions": [0.5, 0.25, 0.25], **split}))
    (out / "dataset.json").write_text(json.dumps({
        "format": DATASET_FORMAT, "version": 1, "n_frames": N_FRAMES, "shifts": shifts, "size_px": list(SIZE),
        "markers": markers, "finger": "left", "depth_binning": estimator_settings(load_settings()).depth_binning,
        "samples": counts, "measurement_version": MEASUREMENT_VERSION, "objects": {k: len(v) for k, v in split.items()},
    }))
    return out


@pytest.fixture(scope="session")
def synthetic() -> SimpleNamespace:
    """The synthetic-data helpers and constants (test modules cannot import conftest)."""
    return SimpleNamespace(sample=synthetic_sample, write_dataset=write_synthetic_dataset, N_FRAMES=N_FRAMES,
                           SIZE=SIZE, OBJECTS=OBJECTS)


@pytest.fixture(scope="session")
def synthetic_dataset(tmp_path_factory) -> Path:
    return write_synthetic_dataset(tmp_path_factory.mktemp("dataset"), markers=True)


@pytest.fixture(scope="session")
def trained_model(synthetic_dataset, tmp_path_factory) -> Path:
    """A hybrid depth model trained for a few epochs on the synthetic dataset (a few seconds)."""
    from estimator.inference.inputs import Variant
    from estimator.training.recipe import TrainConfig
    from estimator.training.train import train_model

    out = tmp_path_factory.mktemp("model")
    variant = Variant.parse("depth+fw+analytical", n_frames=N_FRAMES, size_px=SIZE)
    train_model(synthetic_dataset, out, variant=variant,
                config=TrainConfig(epochs=4, patience=4, batch_size=8, seed=1), progress=False)
    return out


SIM_OBJECTS = ("stress_ball", "rubber_duck", "silicone_ball_shore00_30", "steel_ball_bearing")


@pytest.fixture(scope="session")
def sim_grasps(tmp_path_factory) -> tuple[Path, Path]:
    """(records directory, calibration file): simulated grasps of a few catalogue objects, soft to
    rigid, and a calibration of the estimator's finger fitted on simulated ball presses (~10 s)."""
    from estimator.perception.calibration_fit import fit_calibration
    from estimator.perception.presses import load_presses
    from teleop.catalogue import load_catalogue
    from teleop.record import write_record
    from teleop.settings import CONFIG_DIR
    from teleop.sim.grasp import simulate_grasp
    from teleop.sim.optics import OpticsRenderer
    from teleop.sim.presses import simulate_presses, write_presses

    out = tmp_path_factory.mktemp("sim")
    settings = load_settings()
    sensor = settings.sensor(settings.sensing.finger)
    camera = OpticsRenderer(sensor, sim=settings.simulation, rng=np.random.default_rng(1))
    pack = simulate_presses(camera, n=16, ball_radius_m=2e-3, depth_range_m=(3e-4, 1e-3),
                            rng=np.random.default_rng(2))
    presses = load_presses(write_presses(out / "presses.npz", pack)).in_sensor_frame(sensor)
    calibration = fit_calibration(presses.reference, presses.images, presses.centers_px, presses.radii_px,
                                  ball_radius_m=2e-3, pixel_pitch_m=sensor.pixel_pitch_m)
    cal_path = calibration.save(out / "calibration.npz")
    objects = {o.name: o for o in load_catalogue(CONFIG_DIR / "objects.toml")}
    records = out / "records"
    records.mkdir()
    for i, name in enumerate(SIM_OBJECTS):
        record, _ = simulate_grasp(objects[name], settings=settings, rng=np.random.default_rng(100 + i), seed=100 + i)
        write_record(record, records / f"{name}.grasp")
    return records, cal_path


@pytest.fixture(scope="session")
def records(settings) -> dict[str, GraspRecord]:
    """A soft and a rigid simulated grasp (a few seconds)."""
    objects = {o.name: o for o in load_catalogue(CONFIG_DIR / "objects.toml")}
    return {name: simulate_grasp(objects[name], settings=settings, rng=np.random.default_rng(seed))[0]
            for name, seed in (("stress_ball", 11), ("steel_ball_bearing", 12))}


@pytest.fixture
def rig(settings, calibration, tmp_path) -> Iterator[Rig]:
    rig = Rig(settings, calibration, report=tmp_path / "estimator.jsonl")
    yield rig
    rig.close()


@pytest.fixture(scope="session")
def measured() -> GraspMeasurements:
    """The shipped reference grasp, measured for every method (its depth too)."""
    reference = Path(__file__).resolve().parents[2] / "estimator" / "models" / "reference.grasp"
    return measure_grasp(read_record(reference), settings=load_settings())
