"""Driving-style inference (Eq. 5): tokens, masks, classifier, split, metrics, training, CLI."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest
import torch
from style_helpers import make_generated_dataset

from envs.style import (
    DEFAULT_CLASSIFIER_PATH,
    SLOT_FEATURES,
    SLOT_NAMES,
    STYLES,
    DrivingStyleClassifier,
    LogisticRegressionBaseline,
    SlotSequences,
    StyleClassifierConfig,
    StyleDataset,
    StyleTrainConfig,
    classification_metrics,
    collect_style_dataset,
    confusion_matrix,
    evaluate_style_classifier,
    load_classifier,
    main,
    masked_mean,
    split_by_episode,
    style_loss,
    summary_features,
    train_style_classifier,
    valid_mask,
)

F = len(SLOT_FEATURES)


def _feats(value: float) -> np.ndarray:
    return np.full((6, F), value, dtype=np.float32)


# ---------------------------------------------------------------------------- contract
def test_contract_matches_environment():
    from envs import mixed_traffic
    assert tuple(mixed_traffic.STYLES) == STYLES
    assert tuple(mixed_traffic.SLOT_NAMES) == SLOT_NAMES
    assert tuple(mixed_traffic.SLOT_FEATURES) == SLOT_FEATURES


# ---------------------------------------------------------------------------- tokens and masks
def test_valid_mask_is_right_aligned():
    expected = np.array(
        [[False, False, False, False], [False, False, False, True], [False, True, True, True], [True] * 4]
    )
    np.testing.assert_array_equal(valid_mask(np.array([0, 1, 3, 4]), 4), expected)


def test_slot_sequences_shapes_and_growth():
    seqs = SlotSequences(seq_len=3, n_features=F)
    ids = ("a", "b", "c", "d", "e", "f")
    present = np.ones(6, dtype=bool)
    assert seqs.tokens.shape == (6, 3, F) and seqs.valid.shape == (6, 3)
    for t in range(1, 5):
        seqs.update(ids, _feats(t), present)
    np.testing.assert_array_equal(seqs.lengths, [3] * 6)  # capped at seq_len
    # newest last: tokens hold steps 2, 3, 4
    np.testing.assert_array_equal(seqs.tokens[0, :, 0], [2.0, 3.0, 4.0])
    assert seqs.valid.all()
    assert not seqs.changed.any()


def test_slot_sequences_occupant_change_and_empty_slot():
    seqs = SlotSequences(seq_len=4, n_features=F)
    present = np.ones(6, dtype=bool)
    seqs.update(("a", "b", "c", "d", "e", "f"), _feats(1), present)
    seqs.update(("a", "b", "c", "d", "e", "f"), _feats(2), present)
    np.testing.assert_array_equal(seqs.changed, [False] * 6)
    # slot 0 gets a new vehicle, slot 2 empties
    present2 = present.copy()
    present2[2] = False
    seqs.update(("z", "b", "", "d", "e", "f"), _feats(3), present2)
    np.testing.assert_array_equal(seqs.lengths, [1, 3, 0, 3, 3, 3])
    np.testing.assert_array_equal(seqs.changed, [True, False, False, False, False, False])
    np.testing.assert_array_equal(seqs.tokens[0, :, 0], [0.0, 0.0, 0.0, 3.0])  # old history dropped
    np.testing.assert_array_equal(seqs.valid[0], [False, False, False, True])
    np.testing.assert_array_equal(seqs.tokens[1, :, 0], [0.0, 1.0, 2.0, 3.0])
    assert not seqs.tokens[2].any() and not seqs.valid[2].any()
    assert seqs.ids[2] == ""
    # the slot fills again: a new sequence, flagged as changed
    seqs.update(("z", "b", "c", "d", "e", "f"), _feats(4), present)
    assert seqs.lengths[2] == 1 and seqs.changed[2] and seqs.tokens[2, -1, 0] == 4.0
    seqs.reset()
    assert not seqs.lengths.any() and not seqs.tokens.any() and seqs.ids == [""] * 6


def test_slot_sequences_rejects_bad_shapes():
    seqs = SlotSequences(seq_len=4, n_features=F)
    with pytest.raises(ValueError, match="features"):
        seqs.update(("a",) * 6, np.zeros((6, F + 1)), np.ones(6, bool))
    with pytest.raises(ValueError, match="present"):
        seqs.update(("a",) * 5, np.zeros((6, F)), np.ones(6, bool))
    with pytest.raises(ValueError, match="seq_len"):
        SlotSequences(seq_len=0)


# ---------------------------------------------------------------------------- configs
def test_config_unknown_key_and_bad_values():
    with pytest.raises(ValueError, match="d_modle"):
        StyleClassifierConfig.from_dict({"d_modle": 16})
    with pytest.raises(ValueError, match="n_heads"):
        StyleClassifierConfig(d_model=30, n_heads=4)
    with pytest.raises(ValueError, match="n_classes"):
        StyleClassifierConfig(n_classes=1)
    with pytest.raises(ValueError, match="seq_len"):
        StyleClassifierConfig(seq_len=0)
    with pytest.raises(ValueError, match="patiense"):
        StyleTrainConfig.from_dict({"patiense": 3})
    with pytest.raises(ValueError, match="val_fraction"):
        StyleTrainConfig(val_fraction=0.6, test_fraction=0.5)
    with pytest.raises(ValueError, match="config"):
        DrivingStyleClassifier(config=3)


# ---------------------------------------------------------------------------- network pieces
def test_masked_mean():
    valid = torch.tensor([[False, True, True], [False, False, False]])
    h = torch.tensor([[[9.0], [1.0], [3.0]], [[5.0], [5.0], [5.0]]])
    assert masked_mean(h, valid).tolist() == [[2.0], [0.0]]


def test_style_loss_matches_eq5_by_hand():
    logits = torch.log(torch.tensor([[0.7, 0.2, 0.1], [0.25, 0.25, 0.5]]))
    labels = torch.tensor([0, 2])
    expected = -(math.log(0.7) + math.log(0.5)) / 2
    assert float(style_loss(logits, labels)) == pytest.approx(expected, rel=1e-6)
    w = torch.tensor([1.0, 1.0, 3.0])  # weighted mean: (1*-log .7 + 3*-log .5) / 4
    assert float(style_loss(logits, labels, w)) == pytest.approx(
        -(math.log(0.7) + 3 * math.log(0.5)) / 4, rel=1e-6
    )


def test_classifier_shapes_padding_invariance_and_empty_rows():
    model = DrivingStyleClassifier(StyleClassifierConfig(seq_len=5, d_model=16, n_heads=2)).eval()
    rng = np.random.default_rng(0)
    tokens = rng.normal(size=(4, 5, F)).astype(np.float32)
    valid = valid_mask(np.array([5, 2, 0, 1]), 5)
    p = model.predict_proba(tokens, valid)
    assert p.shape == (4, 3) and p.dtype == np.float32
    np.testing.assert_allclose(p[[0, 1, 3]].sum(1), 1.0, rtol=1e-5)
    np.testing.assert_array_equal(p[2], [0.0, 0.0, 0.0])  # empty slot: "no vehicle" = zeros
    np.testing.assert_allclose(model.predict_proba(tokens, valid, empty="uniform")[2], [1 / 3] * 3)
    garbage = tokens.copy()
    garbage[~valid] = 1e3  # padded positions must not matter
    np.testing.assert_allclose(model.predict_proba(garbage, valid), p, atol=1e-6)
    with pytest.raises(ValueError, match="tokens"):
        model.predict_proba(tokens[:, :4], valid[:, :4])
    with pytest.raises(ValueError, match="empty"):
        model.predict_proba(tokens, valid, empty="nan")


def test_save_load_roundtrip(tmp_path):
    model = DrivingStyleClassifier(
        StyleClassifierConfig(seq_len=4, d_model=8, n_heads=2), metadata={"k": [1, 2]}
    )
    model.fit_normalizer(np.arange(4 * 4 * F, dtype=np.float32).reshape(4, 4, F), np.ones((4, 4), bool))
    path = tmp_path / "sub" / "clf.pt"
    model.save(path)
    loaded = load_classifier(str(path))
    assert loaded.config == model.config and loaded.metadata == {"k": [1, 2]}
    tokens = np.random.default_rng(1).normal(size=(3, 4, F)).astype(np.float32)
    valid = np.ones((3, 4), bool)
    np.testing.assert_array_equal(
        loaded.predict_proba(tokens, valid), model.eval().predict_proba(tokens, valid)
    )
    with pytest.raises(ValueError, match="not found"):
        DrivingStyleClassifier.load(tmp_path / "missing.pt")
    torch.save({"something": 1}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not a DrivingStyleClassifier"):
        DrivingStyleClassifier.load(tmp_path / "other.pt")
    with pytest.raises(ValueError, match="classifier must be"):
        load_classifier(42)


def test_fit_normalizer_uses_valid_tokens_only():
    model = DrivingStyleClassifier(StyleClassifierConfig(seq_len=2, d_model=8, n_heads=2))
    tokens = np.zeros((2, 2, F), dtype=np.float32)
    tokens[0, 1] = 2.0
    tokens[1, 1] = 4.0
    tokens[:, 0] = 1000.0  # padding
    model.fit_normalizer(tokens, np.array([[False, True], [False, True]]))
    np.testing.assert_allclose(model.feature_mean.numpy(), 3.0)
    np.testing.assert_allclose(model.feature_std.numpy(), 1.0)


# ---------------------------------------------------------------------------- split
def test_split_by_episode_has_no_leakage():
    episodes = np.repeat(np.arange(20), 7)
    train, val, test = split_by_episode(episodes, 0.15, 0.15, seed=3)
    sets = [set(episodes[i]) for i in (train, val, test)]
    assert not (sets[0] & sets[1]) and not (sets[0] & sets[2]) and not (sets[1] & sets[2])
    assert len(sets[2]) == 3 and len(sets[1]) == 3 and len(sets[0]) == 14
    np.testing.assert_array_equal(np.sort(np.concatenate([train, val, test])), np.arange(140))
    again = split_by_episode(episodes, 0.15, 0.15, seed=3)
    for a, b in zip((train, val, test), again, strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="at least 3"):
        split_by_episode(np.array([0, 0, 1]))


def test_training_split_is_stored_and_disjoint():
    ds = make_generated_dataset(n_episodes=6, per_episode=20, seq_len=4)
    model, hist = train_style_classifier(
        ds,
        {"d_model": 8, "n_heads": 2, "dim_feedforward": 8},
        {"max_epochs": 1, "val_fraction": 0.2, "test_fraction": 0.2},
        progress_bar=False,
    )
    split = model.metadata["split_episodes"]
    assert set(split["train"]).isdisjoint(split["test"]) and set(split["val"]).isdisjoint(split["test"])
    assert sorted(split["train"] + split["val"] + split["test"]) == list(range(6))
    assert len(hist["val_loss"]) == 1


# ---------------------------------------------------------------------------- metrics
def test_confusion_matrix_rows_inferred_columns_truth():
    truth = np.array([0, 0, 0, 1, 1, 2])
    pred = np.array([0, 0, 1, 1, 2, 2])
    m = confusion_matrix(pred, truth, 3)
    np.testing.assert_array_equal(m, [[2, 0, 0], [1, 1, 0], [0, 1, 1]])
    metrics = classification_metrics(m)
    assert metrics["accuracy"] == pytest.approx(4 / 6)
    assert metrics["macro_accuracy"] == pytest.approx((2 / 3 + 1 / 2 + 1) / 3)
    assert metrics["per_class"]["neutral"] == {"precision": 0.5, "recall": 0.5, "support": 2}
    assert metrics["per_class"]["aggressive"]["precision"] == pytest.approx(0.5)
    with pytest.raises(ValueError, match="predicted"):
        confusion_matrix(np.array([3]), np.array([0]), 3)


def test_summary_features_by_hand():
    tokens = np.zeros((1, 3, F), dtype=np.float32)
    tokens[0, :, 0] = [99.0, 1.0, 3.0]  # first position is padding
    s = summary_features(tokens, np.array([[False, True, True]]))
    assert s.shape == (1, 5 * F + 1)
    assert s[0, 0] == 2.0 and s[0, F] == 1.0 and s[0, 2 * F] == 1.0 and s[0, 3 * F] == 3.0
    assert s[0, 4 * F] == 3.0 and s[0, -1] == 2.0


def test_dataset_validation_and_roundtrip(tmp_path):
    ds = make_generated_dataset(n_episodes=3, per_episode=5, seq_len=4)
    ds.save(tmp_path / "d.npz")
    back = StyleDataset.load(tmp_path / "d.npz")
    np.testing.assert_array_equal(back.tokens, ds.tokens)
    assert back.meta == ds.meta and len(back) == 15
    short = ds.truncate(2)
    assert short.tokens.shape == (15, 2, F) and short.meta["seq_len"] == 2
    np.testing.assert_array_equal(short.lengths, np.minimum(ds.lengths, 2))
    np.testing.assert_array_equal(short.tokens, ds.tokens[:, -2:])
    with pytest.raises(ValueError, match="exceeds"):
        ds.truncate(5)
    with pytest.raises(ValueError, match="labels"):
        StyleDataset(ds.tokens, ds.valid, ds.labels[:3], ds.episodes, ds.slots)
    empty_valid = ds.valid.copy()
    empty_valid[0] = False
    with pytest.raises(ValueError, match="valid token"):
        StyleDataset(ds.tokens, empty_valid, ds.labels, ds.episodes, ds.slots)


# ---------------------------------------------------------------------------- learning
def test_small_classifier_beats_chance_and_baseline_is_sane():
    ds = make_generated_dataset(n_episodes=12, per_episode=80, seq_len=10, seed=0)
    model, hist = train_style_classifier(
        ds,
        {"d_model": 16, "n_heads": 2, "dim_feedforward": 32},
        {
            "max_epochs": 12,
            "batch_size": 128,
            "learning_rate": 3e-3,
            "val_fraction": 0.17,
            "test_fraction": 0.17,
        },
        progress_bar=False,
    )
    res = evaluate_style_classifier(model, ds)
    # chance is 1/3; the generated styles are separable from whole sequences but not from one token
    assert res["macro_accuracy"] > 0.6, res
    assert res["baseline"]["macro_accuracy"] > 0.5
    assert np.asarray(res["confusion_matrix"]).sum() == res["n"] == 2 * 80  # 2 test episodes
    assert hist["best_epoch"] >= 0
    json.dumps(res)  # JSON-serialisable


def test_logistic_baseline_separates_linear_data():
    rng = np.random.default_rng(0)
    labels = rng.integers(0, 3, 300)
    tokens = rng.normal(size=(300, 4, F)).astype(np.float32) * 0.1
    tokens[..., 2] += labels[:, None] * 1.0
    valid = np.ones((300, 4), bool)
    lr = LogisticRegressionBaseline().fit(tokens, valid, labels, 3)
    assert (lr.predict_proba(tokens, valid).argmax(1) == labels).mean() > 0.97


# ---------------------------------------------------------------------------- CLI
def test_cli_train_and_evaluate(tmp_path, capsys):
    ds = make_generated_dataset(n_episodes=6, per_episode=20, seq_len=4)
    ds.save(tmp_path / "d.npz")
    assert (
        main(
            [
                "train",
                "--data",
                str(tmp_path / "d.npz"),
                "--out",
                str(tmp_path / "m.pt"),
                "--no-progress",
                "--model",
                "d_model=8",
                "n_heads=2",
                "--train",
                "max_epochs=2",
                "val_fraction=0.2",
                "test_fraction=0.2",
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "evaluate",
                "--data",
                str(tmp_path / "d.npz"),
                "--model",
                str(tmp_path / "m.pt"),
                "--json",
                str(tmp_path / "r" / "eval.json"),
                "--png",
                str(tmp_path / "r" / "cm.png"),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "inferred \\ truth" in out and "baseline" in out
    res = json.loads((tmp_path / "r" / "eval.json").read_text())
    assert {"macro_accuracy", "confusion_matrix", "per_class", "baseline"} <= set(res)
    assert (tmp_path / "r" / "cm.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(SystemExit):
        main(["train", "--data", str(tmp_path / "d.npz"), "--model", "d_modle=8", "--no-progress"])
    assert "d_modle" in capsys.readouterr().err


@pytest.mark.parametrize("module_args", [["envs", "style"], ["envs.style"]])
def test_cli_entry_points(module_args):
    """Both spellings of the command line reach the same parser."""
    done = subprocess.run(
        [sys.executable, "-m", *module_args, "--help"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: python -m envs.style [-h] {collect,train,evaluate}")


def test_package_reexports_every_public_name():
    import envs.style as style_pkg
    from envs.style import cli, data, model, train

    assert style_pkg.main is cli.main and style_pkg.StyleDataset is data.StyleDataset
    assert style_pkg.DrivingStyleClassifier is model.DrivingStyleClassifier
    assert style_pkg.train_style_classifier is train.train_style_classifier
    assert all(hasattr(style_pkg, name) for name in style_pkg.__all__)
    # the packaged classifier sits next to the package, not inside it
    assert DEFAULT_CLASSIFIER_PATH.parent.name == "data"
    assert DEFAULT_CLASSIFIER_PATH.parent.parent.name == "envs"


# ---------------------------------------------------------------------------- environment and package data
def test_collect_from_mixed_traffic():
    ds = collect_style_dataset(
        3, seq_len=6, stride=2, seed=5, max_steps_per_episode=30, sumo_driver_fraction=0.5, progress_bar=False
    )
    assert len(ds) > 0 and ds.tokens.shape[1:] == (6, F)
    assert set(np.unique(ds.episodes)) <= {0, 1, 2}
    assert ds.labels.min() >= 0 and ds.labels.max() < len(STYLES)
    assert ds.valid[:, -1].all()  # the newest token is always valid
    np.testing.assert_array_equal(ds.tokens[~ds.valid], 0.0)
    assert ds.meta["seq_len"] == 6 and ds.meta["features"] == list(SLOT_FEATURES)
    with pytest.raises(ValueError, match="sumo_driver_fraction"):
        collect_style_dataset(1, sumo_driver_fraction=2.0)


def test_packaged_classifier_loads():
    assert DEFAULT_CLASSIFIER_PATH.is_file(), "the package ships its default classifier (setup.cfg package_data)"
    model = load_classifier(None)
    assert model.config.n_features == len(SLOT_FEATURES) and model.config.n_classes == len(STYLES)
    assert model.metadata["styles"] == list(STYLES) and model.metadata["features"] == list(SLOT_FEATURES)
    assert DEFAULT_CLASSIFIER_PATH.stat().st_size < 300_000
