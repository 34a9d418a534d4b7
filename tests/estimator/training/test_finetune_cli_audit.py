"""``estimator fine-tune``'s command line: its options reach fine-tuning, and what is missing is named first."""

from __future__ import annotations

import json
import shutil

import pytest

from estimator.cli import main
from estimator.errors import EstimatorError, ModelError
from estimator.inference.infer import default_model_dir
from estimator.inference.reference import REFERENCE_RECORD
from estimator.training import finetune as finetune_module
from estimator.training import finetune_cli
from estimator.training.finetune_cli import check_text, fine_tune_and_report
from estimator.training.recipe import FINE_TUNE_CONFIG, TrainConfig

FAKE_TUNING = {"objects": ["foam_a", "metal_b"], "grasps": 3, "samples": 6, "seconds": 2.0,
               "history": [{"epoch": 1, "train_loss": 0.9}, {"epoch": 2, "train_loss": 0.4}]}


@pytest.fixture
def data(synthetic, tmp_path):
    return synthetic.write_dataset(tmp_path / "data", grasps=1, shifts=1)


def _never(*args, **kwargs):
    raise AssertionError("reached past the check that should have refused")


def test_the_command_passes_every_option_to_fine_tuning(tmp_path, monkeypatch):
    got = {}
    monkeypatch.setattr(finetune_cli, "fine_tune_and_report",
                        lambda *args, **kwargs: got.update(args=args, **kwargs) or 0)
    assert main(["fine-tune", "--model", "m", "--data", "d", "--out", "o", "--replay", "r", "--replay-ratio", "2.5",
                 "--epochs", "3", "--lr", "0.01", "--batch-size", "4", "--seed", "7", "--overwrite"]) == 0
    assert got["args"] == ("m", "d", "o")
    assert got["config"] == TrainConfig(epochs=3, lr=0.01, batch_size=4, seed=7,
                                        weight_decay=FINE_TUNE_CONFIG.weight_decay,
                                        label_sd_decades=FINE_TUNE_CONFIG.label_sd_decades)
    assert (got["replay"], got["replay_ratio"], got["overwrite"]) == ("r", 2.5, True)
    assert got["check_settings"] is None and got["compare"] is None and got["as_json"] is False


def test_a_model_folder_without_metadata_is_refused_naming_the_option(data, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ModelError, match=r"^--init .*empty: no metadata.json in it; expected a trained model"):
        fine_tune_and_report(str(empty), str(data), str(tmp_path / "out"), config=FINE_TUNE_CONFIG, replay=None,
                             replay_ratio=1, model_option="--init")
    with pytest.raises(ModelError, match=r"^--model .*gone: no such directory"):
        fine_tune_and_report(str(tmp_path / "gone"), str(data), str(tmp_path / "out"), config=FINE_TUNE_CONFIG,
                             replay=None, replay_ratio=1)
    assert not (tmp_path / "out").exists()


def test_a_replay_that_is_not_a_dataset_is_refused_naming_the_option(data, tmp_path):
    for replay, what in ((tmp_path / "gone", "no such directory"), (tmp_path, "no dataset.json in it")):
        with pytest.raises(EstimatorError, match=f"^--replay {replay}: {what}; expected the base model's training"):
            fine_tune_and_report(str(default_model_dir()), str(data), str(tmp_path / "out"), config=FINE_TUNE_CONFIG,
                                 replay=str(replay), replay_ratio=1)
    assert not (tmp_path / "out").exists()


def test_a_data_folder_that_is_not_a_dataset_is_refused_before_any_work(tmp_path, monkeypatch):
    monkeypatch.setattr(finetune_module, "fine_tune", _never)
    (tmp_path / "d").mkdir()
    with pytest.raises(EstimatorError, match=str(tmp_path / "d")):
        fine_tune_and_report(str(default_model_dir()), str(tmp_path / "d"), str(tmp_path / "out"),
                             config=FINE_TUNE_CONFIG, replay=None, replay_ratio=1)


def test_the_base_model_as_the_output_is_refused_before_the_check_fine_tunes(data, monkeypatch):
    monkeypatch.setattr(finetune_module, "check_by_object", _never)
    model = str(default_model_dir())
    with pytest.raises(EstimatorError, match="is the base model"):
        fine_tune_and_report(model, str(data), model, config=FINE_TUNE_CONFIG, replay=None, replay_ratio=1,
                             check_settings=object())


def test_records_to_compare_of_only_trained_objects_are_refused_before_fine_tuning(data, tmp_path, monkeypatch):
    monkeypatch.setattr(finetune_module, "fine_tune", _never)
    split = json.loads((data / "split.json").read_text())
    split["test"].append("molded_cylinder_wide")  # the reference record's object: now a fine-tuning object
    (data / "split.json").write_text(json.dumps(split))
    records = tmp_path / "records"
    records.mkdir()
    shutil.copy(REFERENCE_RECORD, records / "one.grasp")
    with pytest.raises(EstimatorError, match=rf"^--compare {records}: no labelled record of an object neither .*"
                                             r"\(1 trained on\)"):
        fine_tune_and_report(str(default_model_dir()), str(data), str(tmp_path / "out"), config=FINE_TUNE_CONFIG,
                             replay=None, replay_ratio=1, compare=str(records))


def test_the_summary_gives_the_last_epochs_loss(data, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(finetune_module, "fine_tune", lambda *args, **kwargs: {"fine_tuning": FAKE_TUNING})
    out = str(tmp_path / "out")
    assert fine_tune_and_report(str(default_model_dir()), str(data), out, config=FINE_TUNE_CONFIG, replay=None,
                                replay_ratio=1, as_json=True) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary == {"out": out, "objects": ["foam_a", "metal_b"], "grasps": 3, "samples": 6, "seconds": 2.0,
                       "final_train_loss": 0.4}
    assert fine_tune_and_report(str(default_model_dir()), str(data), out, config=FINE_TUNE_CONFIG, replay=None,
                                replay_ratio=1) == 0
    shown = capsys.readouterr().out
    assert "on 3 grasps (6 samples) of 2 objects" in shown and "final train loss 0.400" in shown
    assert f"estimator compare RECORDS --base {default_model_dir()} --candidate {out}" in shown


def test_grasps_shown_unknown_only_after_fine_tuning_are_said(tmp_path):
    before = {"n": 4, "shown_unknown": 0, "felt_log10_error": 0.3, "felt_within_2x": 0.5, "dangerous_misses": 0}
    after = {**before, "shown_unknown": 2}
    assert "shown unknown 0 -> 2, left out of the felt figures" in check_text({"base": before, "fine_tuned": after})
    assert "shown unknown" not in check_text({"base": before, "fine_tuned": before})
