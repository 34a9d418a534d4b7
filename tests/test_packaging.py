"""The project as an installable product: the wheel carries the code, ``configs/`` and the models.

``pyproject.toml`` lists the packages (``teleop._configs`` maps onto the top-level ``configs/``
folder, so it cannot be found by discovery); the fast test keeps that list in step with the tree.
The slow test builds the wheel from a copy of the sources, installs it into a fresh virtual
environment (dependencies from the running interpreter's site-packages) and runs the installed
package from a folder outside the checkout.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tomllib
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
PACKAGES = ("teleop", "estimator", "haptics")
SHIPPED_CONFIGS = "teleop._configs"


def _source_packages() -> set[str]:
    return {".".join(init.parent.relative_to(REPO).parts)
            for top in PACKAGES for init in (REPO / top).rglob("__init__.py")}


def test_pyproject_lists_every_package_and_ships_configs():
    tool = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]
    assert set(tool["packages"]) == _source_packages() | {SHIPPED_CONFIGS}, (
        "pyproject.toml [tool.setuptools] packages must list every package of the tree")
    assert tool["package-dir"] == {SHIPPED_CONFIGS: "configs"}


# --------------------------------------------------------------------------- the installed wheel

#: Run by the installed interpreter in a folder outside the checkout.
_CHECK = r"""
import json, sys
from pathlib import Path
import teleop, estimator, haptics
from teleop.settings import config_dir, load_settings, resolve_path
from teleop.scene import load_scene
from teleop.catalogue import load_catalogue, default_catalogue_path
from estimator.measurements import calibration_path
from estimator.perception.calibration import load_calibration
from estimator.inference.infer import default_model_dir
from estimator.inference.reference import REFERENCE_RECORD

settings = load_settings()
scene = load_scene("quick")
calibrations = [str(calibration_path(s)) for s in settings.sensors if s.calibration]
for path in calibrations:
    load_calibration(path)
rigs = {p.stem: [str(resolve_path(s.calibration)) for s in load_settings(p).sensors]
        for p in sorted((config_dir() / "rigs").glob("*.toml"))}
for paths in rigs.values():
    for path in paths:
        load_calibration(path)
metadata = json.loads((default_model_dir() / "metadata.json").read_text())
print(json.dumps({
    "modules": [m.__file__ for m in (teleop, estimator, haptics)],
    "config_dir": str(config_dir()),
    "catalogue": str(default_catalogue_path()),
    "objects": len(load_catalogue(default_catalogue_path())),
    "scene_objects": [o.name for o in scene.objects],
    "calibrations": calibrations,
    "rigs": rigs,
    "model_dir": str(default_model_dir()),
    "model_onnx": (default_model_dir() / "model.onnx").is_file(),
    "model_format": metadata.get("format"),
    "reference_record": REFERENCE_RECORD.is_file(),
}))
"""


def _site_packages() -> list[str]:
    """The running interpreter's site-packages: the installed wheel's dependencies."""
    paths = sysconfig.get_paths()
    return list(dict.fromkeys([paths["purelib"], paths["platlib"]]))


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, dict[str, str], Path]:
    """(the fresh environment's bin folder, the environment to run it with, a folder outside the
    checkout) after building the wheel and installing it there."""
    root = tmp_path_factory.mktemp("wheel")
    source = root / "source"  # a copy: the build's build/ and egg-info stay out of the checkout
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info", "build")
    for name in (*PACKAGES, "configs"):
        shutil.copytree(REPO / name, source / name, ignore=ignore)
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / name, source / name)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "PIP_REQUIRE_VIRTUALENV")}
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "--no-build-isolation",
                    "--no-index", "-q", "-w", str(root / "dist")], check=True, env=env, cwd=root)
    wheel, = (root / "dist").glob("compliance_teleop-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    expected = {p.relative_to(REPO).as_posix() for top in PACKAGES for p in (REPO / top).rglob("*.py")}
    expected |= {"teleop/_configs/" + p.relative_to(REPO / "configs").as_posix()
                 for p in (REPO / "configs").rglob("*") if p.is_file()}
    models = REPO / "estimator" / "models"
    expected |= {p.relative_to(REPO).as_posix() for pattern in ("*/model.onnx", "*/metadata.json", "*.grasp")
                 for p in models.glob(pattern)}
    assert sorted(expected - names) == []

    venv = root / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, env=env)
    python = venv / "bin" / "python"
    # pip of this interpreter installs into the fresh one, before that one sees any other site-packages.
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index",
                    "-q", str(wheel)], check=True, env=env)
    own = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                         check=True, env=env, capture_output=True, text=True).stdout.strip()
    # A path line only: the .pth files there (this checkout's editable install) are not run.
    Path(own, "zz_dependencies.pth").write_text("".join(f"{p}\n" for p in _site_packages()))
    elsewhere = root / "elsewhere"
    elsewhere.mkdir()
    return venv / "bin", env, elsewhere


@pytest.mark.slow
def test_installed_wheel_finds_its_settings_calibrations_and_models(installed):
    bin_dir, env, elsewhere = installed
    run = subprocess.run([str(bin_dir / "python"), "-c", _CHECK], env=env, cwd=elsewhere,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    found = json.loads(run.stdout.strip().splitlines()[-1])
    venv = bin_dir.parent
    inside = [found["config_dir"], found["catalogue"], found["model_dir"], *found["modules"],
              *found["calibrations"], *(p for paths in found["rigs"].values() for p in paths)]
    outside = [p for p in inside if not Path(p).is_relative_to(venv)]
    assert outside == [], "the installed package reads files of the checkout"
    assert Path(found["config_dir"]).parts[-2:] == ("teleop", "_configs")
    assert found["objects"] > 0 and len(found["scene_objects"]) == 3
    assert found["calibrations"] and set(found["rigs"]) == {"gelsight", "gelsight_mini"}
    assert found["model_onnx"] and found["model_format"] == "compliance-teleop.model"
    assert found["reference_record"]


def _demo(bin_dir: Path, env: dict[str, str], cwd: Path, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(bin_dir / "teleop"), "demo", "--scene", "quick", "--json", "--no-view",
                           "--out", str(out)], env=env, cwd=cwd, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_installed_wheel_runs_the_demo_outside_the_checkout(installed):
    bin_dir, env, elsewhere = installed
    run = _demo(bin_dir, env, elsewhere, elsewhere / "run")
    said = run.stdout + run.stderr
    assert run.returncode == 0, said
    last = json.loads(run.stdout)  # with --json, all of stdout
    assert last["scene"] == "quick" and len(last["grasps"]) == 3
    assert Path(last["session_log"]).is_file()
    assert Path(last["session_log"]).is_relative_to(elsewhere)
    assert "session log:" in run.stderr and "steel_ball_bearing" in run.stderr  # the closing table
