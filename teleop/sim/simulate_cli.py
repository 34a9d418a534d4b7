"""``teleop simulate``: labelled grasp records of catalogue objects, from the grasp simulator.

Each grasp is drawn from its own random stream, seeded by (--seed, object
name, grasp index) (:func:`~teleop.sim.simulate.grasp_rng`), so a seed gives the
same records whatever --workers is and whichever objects are run beside it. One
``<object>_g<index>.grasp`` per grasp (and with --preview a ``.png`` contact sheet
beside it).

With --randomize-rig every grasp is also simulated on its own rig, drawn from the
grasp's random stream before anything else (:mod:`teleop.sim.rig`: gel tolerances,
finger stiffness, target force, closing speed, noise, rates, camera latency,
illumination); the record carries what the lab would know of that rig and keeps
the true values in ``provenance.extra["rig"]``. Without it nothing changes: the
records are byte for byte those of the settings' one rig.

With --operator sim each grasp is driven by a simulated operator (seeded from the grasp's
stream: :class:`~teleop.sim.operator.SimulatedOperator`, variable closing speed, pauses,
back-offs and re-squeezes, different peak forces) in a leader-follower loop instead of the
paper's scripted grasp; the records say ``provenance.style = "operator"``. The object's pose
and the fingers are drawn as for the scripted grasp of the same seed, so the two styles grasp
the same objects alike.

With --vary-contact every grasp also draws the contact mechanics the simulator assumes
(:mod:`teleop.sim.mechanics`: the gel layer's backing and effective thickness, the object's
Poisson's ratio, densification, rubber-like stiffening, friction and size) from a stream of
its own (:func:`~teleop.sim.simulate.mechanics_rng`: the rig, pose and operator stay those of
the grasp without it); the drawn values go to ``provenance.extra["mechanics"]``, never to
what an estimator reads. The gel is never drawn as a half-space, the contact model held out
for testing: --vary-contact with --gel-model half-space is refused.

Every record carries the gripper settings it was simulated with (``record.gripper``, as an exported
session's; with --randomize-rig the rig's known ones), so the estimator reads it on its own rig
whatever its settings say: with --target-force-n, a gripper of that maximum force.

--target-force-n is refused at or below the contact force (the settings' ``[estimator]
contact_force_n``, read from the file as written: ``teleop`` does not import ``estimator``;
:data:`DEFAULT_CONTACT_FORCE_N` when the file sets none), where a grasp never reaches contact and
the estimator could not read the records it gives.

A grasp whose fingers close on each other before the force target (an object too small to
grasp) fails, and with --overwrite no earlier file of its name is left behind.

A worker that dies (killed, out of memory), a record or preview that cannot be written (a full disk:
the error names the file) or an unexpected error in a grasp (not the simulator's
:class:`~teleop.errors.SimulationError`: a bug) ends the run with an error that says what
failed, how many records were written and how to finish. The records written stay: each is written
whole (its preview first, then the record under a temporary name, renamed), and a dead worker's
temporaries and previews without their record are removed; so are those of the workers an interrupt
(Ctrl-C, SIGTERM) stopped mid-write.

A sensor calibration file named in the settings that does not exist is warned of (as ``teleop settings``
words it, with the settings file), not refused: the records are raw frames, simulated without a
calibration, which ``estimator estimate``, ``evaluate`` and ``build-dataset`` read with ``--calibration
CAL`` or once the file they name is made.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import logging
import math
import re
import shlex
import sys
import time
from collections.abc import Iterator
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

from teleop.catalogue import ObjectSpec, default_catalogue_path, load_catalogue
from teleop.clikit import non_negative_int
from teleop.errors import SettingsError, SimulationError
from teleop.parallel import progress_map
from teleop.record import partial_path, safe_name, write_record
from teleop.settings import Settings, default_settings_path, load_settings, missing_calibrations
from teleop.sim.grasp import OPERATORS, TARGET_FORCE_FRACTION, simulate_grasp
from teleop.sim.mechanics import draw_mechanics
from teleop.sim.preview import write_preview
from teleop.sim.rig import draw as draw_rig
from teleop.sim.simulate import check_filenames, grasp_filename, grasp_rng, mechanics_rng

log = logging.getLogger(__name__)

#: ``estimator.settings.EstimatorSettings.contact_force_n``'s default (N): the force the estimator takes
#: for first contact. ``teleop`` may not import ``estimator``, so it is mirrored here (a test compares).
DEFAULT_CONTACT_FORCE_N = 0.75


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--objects", default=str(default_catalogue_path()), metavar="PATH",
                        help="object catalogue: the project's .toml or the published .csv object table")
    parser.add_argument("--grasps-per-object", type=int, default=1, metavar="N",
                        help="grasps simulated per object (each in a newly drawn pose and target force)")
    parser.add_argument("--seed", type=non_negative_int, default=0, metavar="S",
                        help="run seed; with the object name and grasp index it fixes every random draw")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="directory for the .grasp records (created), named OBJECT_gINDEX.grasp")
    parser.add_argument("--overwrite", action="store_true",
                        help="first remove the simulated objects' earlier records in --out (OBJECT_gINDEX.grasp "
                             "and their .png previews, whatever their index; other objects' files are kept), then "
                             "simulate; a preview not made again is not left behind (without it such records are "
                             "refused: another seed's grasps would be lost, or mixed with these)")
    parser.add_argument("--workers", type=int, default=1, metavar="K",
                        help="worker processes; the records do not depend on it")
    parser.add_argument("--preview", action="store_true",
                        help="also write a PNG contact sheet beside each record (frames, true depth, F(t), w(t))")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON summary object as the last stdout line "
                             "(grasps, seconds, grasps_per_s_per_core, out, models, failed)")
    parser.add_argument("--settings", metavar="FILE", default=None,
                        help="settings TOML (default: the shipped configs/settings.toml)")
    parser.add_argument("--limit-objects", type=int, default=None, metavar="M",
                        help="simulate only the first M objects of the catalogue (default: all)")
    parser.add_argument("--only", type=_names, default=None, metavar="NAME,NAME,...",
                        help="simulate only these objects of the catalogue (comma-separated names)")
    parser.add_argument("--randomize-rig", action="store_true",
                        help="simulate each grasp on its own rig drawn from the grasp's random stream "
                             "(teleop.sim.rig.RigSpread: gel modulus +-15 %%, gel thickness +-10 %%, finger "
                             "stiffness 20-500 kN/m, target force 5-30 N, closing speed, noise, rates, camera "
                             "latency, illumination); records carry the rig's known settings, the true ones "
                             "go to their provenance")
    parser.add_argument("--gel-model", choices=("layer", "half-space"), default=None,
                        help="the gel in the contact solver (default: the settings' simulation.gel_model, "
                             "'layer'); 'half-space' simulates with a contact model the estimator was not "
                             "trained on")
    parser.add_argument("--operator", choices=OPERATORS, default="script",
                        help="who drives each grasp: 'script' (the paper's grasp: constant closing speed to one "
                             "target force, hold, release) or 'sim' (a seeded simulated operator in a "
                             "leader-follower loop: variable speed, pauses, back-offs, re-squeezes, peaks from "
                             "3 N up to the settings' maximum grasp force)")
    parser.add_argument("--target-force-n", type=float, default=None, metavar="N",
                        help="the grasps' force ceiling in N instead of the settings' gripper.target_force_n: a "
                             "scripted grasp squeezes to 40-100 %% of it, the simulated operator at most to it "
                             "(e.g. 12 for light grasps of 4.8-12 N); the records' gripper settings carry it; "
                             "not with --randomize-rig, which draws each rig's own; refused at or below the "
                             "estimator's contact force (the settings' estimator.contact_force_n, 0.75 N by "
                             "default)")
    parser.add_argument("--vary-gel", action="store_true",
                        help="with --randomize-rig: also draw each rig's datasheet gel (120-400 kPa, 2.5-4.5 mm), "
                             "as other GelSight-type sensors have; the records carry it")
    parser.add_argument("--vary-contact", action="store_true",
                        help="draw the contact mechanics of each grasp (teleop.sim.mechanics.ContactSpread): the gel "
                             "layer bonded to, sliding on or partly bonded to its backing, its effective thickness "
                             "x0.6-1.5, the object's Poisson's ratio 0.3-0.5, foam densification and rubber-like "
                             "stiffening, friction stiffening 0-5 %%, object size x0.8-1.2 per axis; never the "
                             "held-out half-space gel (refused with --gel-model half-space); the drawn values go "
                             "to the records' provenance only")


class _GraspCrashed(Exception):
    """An error (not a :class:`SimulationError`) simulating or writing one grasp, ``reason`` saying what: it
    ends the run. Its arguments are all it holds, so that it comes back from a worker process whole."""

    def __init__(self, name: str, index: int, reason: str) -> None:
        super().__init__(name, index, reason)
        self.name, self.index, self.reason = name, index, reason


def _names(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"{text!r}: expected comma-separated object names")
    return names


def _earlier_files(out: Path, objects: list[ObjectSpec]) -> list[str]:
    """The files in ``out`` that are records (``<object>_g<index>.grasp``) or previews (``.png``) of
    ``objects``, whatever their index, sorted."""
    patterns = [re.compile(re.escape(safe_name(obj.name)) + r"_g\d{3,}\.(?:grasp|png)") for obj in objects]
    try:
        names = sorted(p.name for p in out.iterdir())
    except OSError as exc:
        raise SettingsError(f"--out {out}: cannot list the directory ({exc.strerror or exc})") from exc
    return [name for name in names if any(p.fullmatch(name) for p in patterns)]


def _contact_force_n(settings: Settings) -> float:
    """The settings file's ``[estimator] contact_force_n`` as written (a finite number > 0), else the
    estimator's default (:data:`DEFAULT_CONTACT_FORCE_N`)."""
    value = settings.tables.get("estimator", {}).get("contact_force_n")
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0:
        return float(value)
    return DEFAULT_CONTACT_FORCE_N


def _check_target_force(target_force_n: float, settings: Settings, settings_path: str | None) -> None:
    """Refuse a --target-force-n at or below the estimator's contact force (module notes); warn when
    some scripted grasps may stay below it."""
    where = settings_path or default_settings_path()
    contact = _contact_force_n(settings)
    if target_force_n <= contact:
        raise SettingsError(f"--target-force-n {target_force_n:g}: expected more than the estimator's contact "
                            f"force, estimator.contact_force_n = {contact:g} N in {where}: the fingers would "
                            "never reach contact and the records give no estimate")
    if TARGET_FORCE_FRACTION[0] * target_force_n <= contact:
        print(f"teleop simulate: warning: --target-force-n {target_force_n:g}: scripted grasps squeeze to "
              f"{TARGET_FORCE_FRACTION[0]:.0%}-{TARGET_FORCE_FRACTION[1]:.0%} of it, so some may stay below the "
              f"estimator's contact force ({contact:g} N, estimator.contact_force_n) and give no estimate",
              file=sys.stderr)


def _warn_missing_calibration(settings: Settings, settings_path: str | None) -> None:
    """Warn (in ``teleop settings``'s words, naming the settings file) of each sensor calibration file the
    settings name that does not exist: the records name it, and the estimator reads them once it exists or
    with ``--calibration CAL``; they are raw frames that need no calibration to simulate (module notes)."""
    where = settings_path or default_settings_path()
    for missing in missing_calibrations(settings, settings_path):
        print(f"teleop simulate: warning: {where}: {missing}: the records are simulated all the same (raw frames) "
              "and name that file: `estimator estimate` reads them once it exists, or with --calibration CAL",
              file=sys.stderr)


def _remove_leftovers(out: Path, jobs: list[tuple]) -> list[tuple[ObjectSpec, int]]:
    """Remove what a worker stopped mid-grasp leaves in ``out`` (a record's temporary, a preview's, a
    preview without its record), so that only whole records stay; returns the (object, index) of the
    jobs without a record."""
    unwritten = []
    for obj, index, *_ in jobs:
        path = out / grasp_filename(obj, index)
        partial_path(path).unlink(missing_ok=True)
        _partial_preview(path).unlink(missing_ok=True)
        if not path.exists():
            path.with_suffix(".png").unlink(missing_ok=True)
            unwritten.append((obj, index))
    return unwritten


def _partial_preview(path: Path) -> Path:
    """The temporary name of the record ``path``'s preview, a name no record takes."""
    return path.with_name(path.stem + ".partial.png")


def _stopped(exc: BaseException, out: Path, jobs: list[tuple]) -> str:
    """What to say when a worker died or a grasp failed unexpectedly: what failed, what was written and
    how to finish. A dead worker's leftovers (a record's temporary, a preview without its record) are
    removed first, so that only whole records stay."""
    if isinstance(exc, _GraspCrashed):
        what = f"{exc.name} grasp {exc.index}: {exc.reason} (-v shows where)"
    else:
        what = "a worker process died (killed? out of memory?)"
    unwritten = _remove_leftovers(out, jobs)
    missing = list(dict.fromkeys(obj.name for obj, _ in unwritten))
    written = f"{len(jobs) - len(unwritten)} of {len(jobs)} records were written to {out}"
    if not missing:
        return f"{what}; {written}: all of them, each whole"
    hint = "" if isinstance(exc, _GraspCrashed) else " and fewer --workers if memory ran short"
    return (f"{what}; the run stopped: {written} (each whole), the rest not: to finish, run the same command "
            f"with --only {shlex.quote(','.join(missing))} --overwrite{hint} (--overwrite replaces those objects' "
            "records of this run: the same --seed gives the same records)")


def _chosen(objects: list[ObjectSpec], names: list[str] | None, where: str) -> list[ObjectSpec]:
    """The objects named in ``names`` (all when None), in catalogue order."""
    if names is None:
        return objects
    unknown = sorted(set(names) - {o.name for o in objects})
    if unknown:
        raise SettingsError(f"--only: {', '.join(unknown)} not in the catalogue {where}")
    return [o for o in objects if o.name in set(names)]


def _simulate_one(job: tuple[ObjectSpec, int, int, Settings, str, bool, bool, bool, str, bool, float | None]) -> dict:
    """Simulate and write one grasp (runs in a worker); the simulator's failures come back as a reason,
    any other error is raised as :class:`_GraspCrashed`, naming the grasp."""
    try:
        return _simulate_and_write(job)
    except _GraspCrashed:
        raise
    except Exception as exc:
        obj, index = job[0], job[1]
        raise _GraspCrashed(obj.name, index, f"unexpected error: {type(exc).__name__}: {exc}") from exc


@contextlib.contextmanager
def _writing(obj: ObjectSpec, index: int, path: Path) -> Iterator[None]:
    """Raise a failed write (a full disk) as the grasp's :class:`_GraspCrashed`, naming the file ``path``:
    the OS error alone does not."""
    try:
        yield
    except OSError as exc:
        raise _GraspCrashed(obj.name, index, f"cannot write {path}: {exc.strerror or exc}") from exc


def _simulate_and_write(job: tuple) -> dict:
    obj, index, seed, settings, out, preview, randomize_rig, vary_gel, operator, vary_contact = job
    path = Path(out) / grasp_filename(obj, index)
    rng = grasp_rng(seed, obj, index)
    mechanics = draw_mechanics(mechanics_rng(seed, obj, index)) if vary_contact else None
    try:
        if randomize_rig:
            rig = draw_rig(settings, rng, vary_gel=vary_gel)
            record, truth = simulate_grasp(obj, settings=rig.true, rng=rng, seed=seed, operator=operator,
                                           mechanics=mechanics)
            record = rig.record(record, finger_stiffness_n_per_m=truth.finger_stiffness_n_per_m,
                                target_force_n=truth.target_force_n)
        else:
            record, truth = simulate_grasp(obj, settings=settings, rng=rng, seed=seed, operator=operator,
                                           mechanics=mechanics)
    except SimulationError as exc:
        # No earlier run's file of this name may pass for this grasp's (run() removed them with --overwrite).
        path.unlink(missing_ok=True)
        path.with_suffix(".png").unlink(missing_ok=True)
        return {"object": obj.name, "grasp": index, "error": str(exc)}
    with _writing(obj, index, path.with_suffix(".png")):
        if preview:
            # Whole before its record (a record's preview is part of it), under a name no record takes.
            sheet = _partial_preview(path)
            try:
                write_preview(record, truth, sheet)
                sheet.replace(path.with_suffix(".png"))
            except BaseException:
                sheet.unlink(missing_ok=True)
                raise
        else:
            # An earlier run's sheet (only there with --overwrite) would pass for this record's.
            path.with_suffix(".png").unlink(missing_ok=True)
    with _writing(obj, index, path):
        write_record(record, path)
    return {"object": obj.name, "grasp": index, "path": str(path), "model": record.provenance.model}


def run(args: argparse.Namespace) -> int:
    if args.grasps_per_object < 1:
        raise SettingsError(f"--grasps-per-object {args.grasps_per_object}: expected 1 or more")
    if args.workers < 1:
        raise SettingsError(f"--workers {args.workers}: expected 1 or more")
    if args.limit_objects is not None and args.limit_objects < 1:
        raise SettingsError(f"--limit-objects {args.limit_objects}: expected 1 or more")
    settings = load_settings(args.settings)
    if len(settings.sensors) != 2:
        raise SettingsError(f"{args.settings or default_settings_path()}: the grasp simulator needs exactly two "
                            f"sensors (one per finger); the settings have {[s.finger for s in settings.sensors]}")
    if args.gel_model is not None:
        settings = dataclasses.replace(
            settings, simulation=dataclasses.replace(settings.simulation, gel_model=args.gel_model))
    if args.target_force_n is not None:
        if args.randomize_rig:
            raise SettingsError("--target-force-n sets the one rig's force ceiling; --randomize-rig draws each "
                                "rig's own: use one of them")
        try:
            gripper = dataclasses.replace(settings.gripper, target_force_n=args.target_force_n)
        except SettingsError as exc:
            raise SettingsError(f"--target-force-n {args.target_force_n:g}: {exc}") from exc
        _check_target_force(args.target_force_n, settings, args.settings)
        settings = dataclasses.replace(settings, gripper=gripper)
    if args.vary_contact and settings.simulation.gel_model != "layer":
        raise SettingsError(f"--vary-contact draws the gel's contact model and never the held-out "
                            f"{settings.simulation.gel_model!r} one: drop --gel-model {settings.simulation.gel_model} "
                            "(or simulation.gel_model in the settings) to vary the contact")
    objects = _chosen(load_catalogue(args.objects), args.only, args.objects)[: args.limit_objects]
    check_filenames(objects, args.objects)
    if args.vary_gel and not args.randomize_rig:
        raise SettingsError("--vary-gel draws a rig's gel: it needs --randomize-rig")
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SettingsError(f"--out {out}: cannot create the directory ({exc.strerror or exc})") from exc
    jobs = [(obj, i, args.seed, settings, str(out), args.preview, args.randomize_rig, args.vary_gel, args.operator,
             args.vary_contact) for obj in objects for i in range(args.grasps_per_object)]
    # A preview is part of its record: a leftover one would be taken for the new record's.
    names = [grasp_filename(obj, i) for obj, i, *_ in jobs]
    taken = []
    for record in names:
        for name in (record, record.removesuffix(".grasp") + ".png"):
            try:
                if (out / name).exists():
                    taken.append(name)
            except OSError as exc:
                # E.g. a name over the file system's limit: say so before any grasp is simulated.
                raise SettingsError(f"--out {out}: cannot use the record file name {name!r} there "
                                    f"({exc.strerror or exc}); shorten the object's name in {args.objects}") from exc
    # Other grasps of these objects (another run's, with more grasps or after a failed one) would mix with these.
    earlier = _earlier_files(out, objects)
    taken += [name for name in earlier if name not in taken]
    if taken and not args.overwrite:
        raise SettingsError(f"--out {out}: {len(taken)} of these records exist already ({', '.join(taken[:3])}"
                            f"{', ...' if len(taken) > 3 else ''}): pass --overwrite to replace them, or another --out")
    for name in earlier:  # with --overwrite: this run's objects only, never another object's files
        try:
            (out / name).unlink(missing_ok=True)
        except OSError as exc:
            raise SettingsError(f"--out {out}: cannot remove the earlier record {name!r} for --overwrite "
                                f"({exc.strerror or exc})") from exc
    workers = min(args.workers, len(jobs))
    _warn_missing_calibration(settings, args.settings)  # once every refusal is past

    start = time.perf_counter()
    try:
        results = progress_map(_simulate_one, jobs, workers=workers, desc="simulate", spawn=True)
    except (BrokenProcessPool, _GraspCrashed) as exc:
        log.info("the run stopped on", exc_info=exc)
        raise SimulationError(_stopped(exc, out, jobs)) from exc
    except KeyboardInterrupt:
        # Ctrl-C or SIGTERM: the pool's workers were stopped at once, mid-write perhaps, with no
        # clean-up of their own (progress_map has joined them: nothing writes here any more).
        _remove_leftovers(out, jobs)
        raise
    seconds = time.perf_counter() - start

    failed = [r for r in results if "error" in r]
    for r in failed:
        log.warning("%s grasp %d not simulated: %s", r["object"], r["grasp"], r["error"])
        print(f"teleop simulate: {r['object']} grasp {r['grasp']}: {r['error']}", file=sys.stderr)
    written = [r for r in results if "path" in r]
    models: dict[str, int] = {}
    for r in written:
        models[r["model"]] = models.get(r["model"], 0) + 1
    summary = {
        "grasps": len(written),
        "seconds": round(seconds, 3),
        "grasps_per_s_per_core": round(len(written) / seconds / max(workers, 1), 3) if seconds > 0 else None,
        "out": str(out),
        "workers": workers,
        "models": models,
        "failed": [{"object": r["object"], "grasp": r["grasp"], "reason": r["error"]} for r in failed],
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"{len(written)} grasp{'' if len(written) == 1 else 's'} in {seconds:.1f} s ({summary['grasps_per_s_per_core']} grasps/s/core) -> {out}")
    return 1 if failed else 0
