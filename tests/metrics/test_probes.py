"""Identity and age probes (PG-BIG App. B.1): separable synthetic embeddings and the Fukuchi runners."""

from __future__ import annotations

import numpy as np
import pytest

from biomotion.errors import DataFormatError
from biomotion.metrics.probes import AgeProbe, IdentityProbe

GLOBAL = ("pelvis_tx", "pelvis_ty", "pelvis_tz")


def test_probes_on_embeddings_with_a_known_answer():
    rng = np.random.default_rng(0)
    centres = rng.normal(size=(5, 8)) * 10
    labels = np.repeat(np.arange(5), 20)
    x = centres[labels] + rng.normal(size=(100, 8))
    identity = IdentityProbe(models=("logistic_regression", "knn", "kernel_svm"))
    identity.update(x[::2], labels[::2], train=True)
    identity.update(x[1::2], labels[1::2], train=False)
    for scores in identity.compute().values():
        assert scores.accuracy == 1.0 and scores.top3 == 1.0 and scores.macro_f1 == 1.0 and scores.n_test == 50
    for predicted in identity.predict().values():
        np.testing.assert_array_equal(predicted, labels[1::2])
    # shuffled labels carry nothing: chance level (1 / 5), top-3 about 3 / 5
    shuffled = IdentityProbe(models=("logistic_regression",))
    shuffled.update(x[::2], rng.permutation(labels[::2]), train=True)
    shuffled.update(x[1::2], rng.permutation(labels[1::2]), train=False)
    chance = shuffled.compute()["logistic_regression"]
    assert chance.accuracy < 0.45 and chance.top3 < 0.85
    age = 20 + 2.0 * x[:, 0]  # exactly linear in the first feature
    probe = AgeProbe(models=("linear_regression",))
    probe.update(x[::2], age[::2], train=True)
    probe.update(x[1::2], age[1::2], train=False)
    result = probe.compute()["linear_regression"]
    assert result.mae == pytest.approx(0.0, abs=1e-9) and result.r2 == pytest.approx(1.0)


def test_probe_input_errors():
    with pytest.raises(DataFormatError, match="models"):
        IdentityProbe(models=("xgboost",))
    probe = AgeProbe(models=("ridge",))
    with pytest.raises(DataFormatError, match="embeddings"):
        probe.update(np.zeros((3, 2)), np.zeros(4), train=True)
    probe.update(np.zeros((3, 2)), np.zeros(3), train=True)
    with pytest.raises(DataFormatError, match="held-out"):
        probe.compute()


def _window_embeddings(values: np.ndarray, size: int = 30, step: int = 15) -> np.ndarray:
    """Per 1 s window (30 frames, half overlap): mean, std, min and max of each coordinate."""
    starts = np.arange(0, values.shape[0] - size + 1, step)
    windows = np.stack([values[s : s + size] for s in starts])
    return np.concatenate([windows.mean(1), windows.std(1), windows.min(1), windows.max(1)], 1)


def test_fukuchi_runners_are_identified_across_speeds(fukuchi_cache):
    """Embeddings of 1 s windows of joint angles (13 lower-body rotations; treadmill translations left out).
    Identity: train on each runner's 2.5 and 4.5 m/s clips, test on the 3.5 m/s clip (held-out strides at an
    unseen speed). Age: the same split (PG-BIG evaluates on the subjects it trained on), and, harder, runners
    of the training split against the val/test runners."""
    cache = fukuchi_cache
    samples = []
    for index in cache.indices(source="fukuchi"):
        motion, record = cache.motion(index), cache.records[index]
        keep = [j for j, name in enumerate(motion.names) if motion.mask[j] and name not in GLOBAL]
        embeddings = _window_embeddings(motion.values[:, keep])
        samples.append(
            (embeddings, record["subject"], cache.profile(index).age, record["labels"]["speed"], record["split"])
        )
    assert len({s[1] for s in samples}) == 23 and samples[0][0].shape[1] == 52
    identity = IdentityProbe(models=("linear_svm", "kernel_svm", "knn"))
    age = AgeProbe(models=("ridge", "knn"))
    unseen_runners = AgeProbe(models=("ridge", "knn"))
    for embeddings, subject, years, speed, split in samples:
        n = len(embeddings)
        identity.update(embeddings, [subject] * n, train=speed != 3.5)
        age.update(embeddings, np.full(n, years), train=speed != 3.5)
        unseen_runners.update(embeddings, np.full(n, years), train=split == "train")
    ident, ages, unseen = identity.compute(), age.compute(), unseen_runners.compute()
    print(
        "Fukuchi identity (test 3.5 m/s):",
        {k: (round(v.accuracy, 3), round(v.top3, 3)) for k, v in ident.items()},
        "| age MAE (years) same runners:",
        {k: round(v.mae, 2) for k, v in ages.items()},
        "| unseen runners:",
        {k: round(v.mae, 2) for k, v in unseen.items()},
    )
    assert ident["kernel_svm"].n_test > 200
    assert min(v.accuracy for v in ident.values()) > 0.85  # chance is 1 / 23
    assert min(v.top3 for v in ident.values()) > 0.95
    assert ages["knn"].mae < 2.0  # the runner is recognised, so is the age
    assert ages["ridge"].mae < 5.0
    # unseen runners: report; only check the probe is not wildly off the mean-age predictor (5.7 years here)
    train_ages = np.concatenate([np.full(len(s[0]), s[2]) for s in samples if s[4] == "train"])
    test_ages = np.concatenate([np.full(len(s[0]), s[2]) for s in samples if s[4] != "train"])
    baseline = np.abs(test_ages - train_ages.mean()).mean()
    assert 0.0 < min(v.mae for v in unseen.values()) < 2 * baseline
