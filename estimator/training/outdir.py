"""The model folder a model command writes (``--out`` of ``estimator train``, ``fine-tune``, ``pool``,
``recalibrate``): checked before any work, and refused when it holds anything unless ``overwrite``, as
``teleop record`` and ``build-dataset`` refuse. Replacing a model there unasked loses the earlier one,
and a service watching the folder takes the new, uncompared one up by itself."""

from __future__ import annotations

from pathlib import Path

from estimator.errors import EstimatorError

__all__ = ["OVERWRITE_HELP", "ModelWriteError", "check_out_dir", "make_out_dir", "model_write_error"]

OVERWRITE_HELP = ("write into a non-empty --out: replace the model.onnx and metadata.json there (and remove an "
                  "earlier training_curve.png; other files stay) instead of refusing. A service watching that "
                  "folder switches to the new model by itself")


def check_out_dir(out_dir: Path, *, overwrite: bool) -> None:
    """Refuse ``out_dir`` before the work that fills it: a file (or under one), or a folder that is not
    empty unless ``overwrite``. Creates nothing.

    Raises
    ------
    EstimatorError
        As above, naming ``--out``.
    """
    existing = next(p for p in (out_dir, *out_dir.parents) if p.exists())
    if not existing.is_dir():
        raise EstimatorError(f"--out {out_dir}: {existing} is a file; expected a folder for the model "
                             "(new or empty)")
    held = sorted(p.name for p in out_dir.iterdir()) if existing is out_dir else []
    if held and not overwrite:
        raise EstimatorError(f"--out {out_dir}: not empty (holds {', '.join(held[:3])}"
                             f"{', ...' if len(held) > 3 else ''}); choose a new or empty folder, or pass "
                             "--overwrite to replace the model in it")


def make_out_dir(out_dir: Path) -> None:
    """Make ``out_dir``, without the training curve an earlier model there left: it would describe
    another network (a command that plots one writes it anew)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "training_curve.png").unlink(missing_ok=True)


class ModelWriteError(EstimatorError):
    """Writing a model into a folder failed (a full or read-only disk); ``cause`` is the OS error."""

    def __init__(self, message: str, cause: OSError):
        super().__init__(message)
        self.cause = cause


def model_write_error(out_dir: Path, exc: OSError) -> ModelWriteError:
    """The error a model command raises when writing its model into ``out_dir`` fails with ``exc``
    (a full or read-only disk): it names the folder and the reason. The writes are staged
    (:func:`~teleop.staging.staged`), so the model there before is whole."""
    return ModelWriteError(f"cannot write the model into {out_dir}: {exc.strerror or exc}; "
                           "the earlier model there is kept (free space or choose another --out)", exc)
