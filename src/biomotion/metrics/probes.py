"""Profile probes (PG-BIG App. B.1, Tables 8-9): do motion embeddings carry who moved, and how old they are?

Standard scikit-learn models are fitted on embeddings of training motions and scored on held-out ones: subject
identity classification (accuracy, top-3 accuracy, macro F1) and age regression (MAE, RMSE, R^2). Embeddings are
any fixed-size vectors per motion (PG-BIG: attention-pooled VQ-VAE encoder latents, 512-d). XGBoost, PG-BIG's best
model, is not a scikit-learn model; histogram gradient boosting stands in for it. Needs the ``ml`` extra
(scikit-learn).

``update(embeddings, targets, train=...)`` collects the training and the held-out samples; ``compute()`` fits
every model and returns one score record per model. Features are standardised (fitted on the training samples).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from biomotion.errors import DataFormatError

CLASSIFIERS = ("logistic_regression", "linear_svm", "kernel_svm", "random_forest", "knn", "mlp", "gradient_boosting")
REGRESSORS = ("linear_regression", "ridge", "random_forest", "knn", "mlp", "gradient_boosting")


@dataclass(frozen=True)
class ClassificationScores:
    """Held-out identity scores of one model (PG-BIG Table 8)."""

    accuracy: float
    top3: float
    macro_f1: float
    n_train: int
    n_test: int


@dataclass(frozen=True)
class RegressionScores:
    """Held-out age-regression scores of one model (PG-BIG Table 9); MAE and RMSE in the target's unit (years)."""

    mae: float
    rmse: float
    r2: float
    n_train: int
    n_test: int


def _classifier(name: str, seed: int):
    from sklearn.ensemble import HistGradientBoostingClassifier, RandomForestClassifier
    from sklearn.linear_model import LogisticRegression
    from sklearn.neighbors import KNeighborsClassifier
    from sklearn.neural_network import MLPClassifier
    from sklearn.svm import SVC, LinearSVC

    return {
        "logistic_regression": lambda: LogisticRegression(max_iter=5000),
        "linear_svm": lambda: LinearSVC(max_iter=20000, random_state=seed),
        "kernel_svm": lambda: SVC(kernel="rbf", decision_function_shape="ovr", random_state=seed),
        "random_forest": lambda: RandomForestClassifier(n_estimators=300, random_state=seed),
        "knn": lambda: KNeighborsClassifier(n_neighbors=5),
        "mlp": lambda: MLPClassifier(hidden_layer_sizes=(128,), max_iter=500, random_state=seed),
        "gradient_boosting": lambda: HistGradientBoostingClassifier(random_state=seed),
    }[name]()


def _regressor(name: str, seed: int):
    from sklearn.compose import TransformedTargetRegressor
    from sklearn.ensemble import HistGradientBoostingRegressor, RandomForestRegressor
    from sklearn.linear_model import LinearRegression, Ridge
    from sklearn.neighbors import KNeighborsRegressor
    from sklearn.neural_network import MLPRegressor
    from sklearn.preprocessing import StandardScaler

    return {
        "linear_regression": lambda: LinearRegression(),
        "ridge": lambda: Ridge(alpha=1.0),
        "random_forest": lambda: RandomForestRegressor(n_estimators=300, random_state=seed),
        "knn": lambda: KNeighborsRegressor(n_neighbors=5),
        "mlp": lambda: TransformedTargetRegressor(  # standardised target: ages are far from the unit scale
            MLPRegressor(hidden_layer_sizes=(128,), max_iter=500, random_state=seed), transformer=StandardScaler()
        ),
        "gradient_boosting": lambda: HistGradientBoostingRegressor(random_state=seed),
    }[name]()


class _Probe:
    """Collects (embedding, target) pairs for a training and a held-out set."""

    known: tuple[str, ...] = ()

    def __init__(self, models: tuple[str, ...] | None = None, seed: int = 0) -> None:
        models = tuple(models) if models is not None else self.known
        unknown = [m for m in models if m not in self.known]
        if unknown or not models:
            raise DataFormatError(None, f"unknown models {unknown}; choose from {self.known}", field="models")
        self.models, self.seed = models, seed
        self.reset()

    def reset(self) -> None:
        self._data: dict[bool, tuple[list[np.ndarray], list[np.ndarray]]] = {True: ([], []), False: ([], [])}

    def update(self, embeddings, targets, *, train: bool) -> None:
        """Add embeddings [N, D] (tensor or array) with their targets [N] to the training or the held-out set."""
        x = np.asarray(embeddings.detach().cpu() if hasattr(embeddings, "detach") else embeddings, dtype=np.float64)
        y = np.asarray(targets.detach().cpu() if hasattr(targets, "detach") else targets)
        if x.ndim != 2 or y.shape != (x.shape[0],):
            raise DataFormatError(
                None, f"embeddings {x.shape} and targets {y.shape} must be [N, D] and [N]", field="embeddings"
            )
        if not np.all(np.isfinite(x)):
            raise DataFormatError(None, "non-finite embedding values", field="embeddings")
        self._data[train][0].append(x)
        self._data[train][1].append(y)

    def _split(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        if not self._data[True][0] or not self._data[False][0]:
            raise DataFormatError(None, "needs both training and held-out samples", field="train")
        (xs, ys), (xt, yt) = self._data[True], self._data[False]
        x_train, x_test = np.concatenate(xs), np.concatenate(xt)
        if x_train.shape[1] != x_test.shape[1]:
            raise DataFormatError(None, "training and held-out embeddings differ in size", field="embeddings")
        mean, std = x_train.mean(0), x_train.std(0)
        std = np.where(std > 0, std, 1.0)
        return (x_train - mean) / std, np.concatenate(ys), (x_test - mean) / std, np.concatenate(yt)


class IdentityProbe(_Probe):
    """Subject identification from embeddings (PG-BIG App. B.1 (i), Table 8): accuracy, top-3, macro F1."""

    known = CLASSIFIERS

    def predict(self) -> dict[str, np.ndarray]:
        """Each model, fitted on the training samples, labels the held-out samples: {model: labels [N]}."""
        x_train, y_train, x_test, _ = self._split()
        return {name: _classifier(name, self.seed).fit(x_train, y_train).predict(x_test) for name in self.models}

    def compute(self) -> dict[str, ClassificationScores]:
        from sklearn.metrics import f1_score

        x_train, y_train, x_test, y_test = self._split()
        results = {}
        for name in self.models:
            model = _classifier(name, self.seed).fit(x_train, y_train)
            scores = model.predict_proba(x_test) if hasattr(model, "predict_proba") else model.decision_function(x_test)
            scores = scores if scores.ndim == 2 else np.stack([-scores, scores], 1)
            ranked = model.classes_[np.argsort(-scores, axis=1)]
            predicted = ranked[:, 0]
            top3 = (ranked[:, :3] == y_test[:, None]).any(1)
            results[name] = ClassificationScores(
                accuracy=float(np.mean(predicted == y_test)),
                top3=float(np.mean(top3)),
                macro_f1=float(f1_score(y_test, predicted, average="macro", zero_division=0)),
                n_train=len(y_train),
                n_test=len(y_test),
            )
        return results


class AgeProbe(_Probe):
    """Age regression from embeddings (PG-BIG App. B.1 (ii), Table 9): MAE, RMSE, R^2 (years)."""

    known = REGRESSORS

    def compute(self) -> dict[str, RegressionScores]:
        from sklearn.metrics import r2_score

        x_train, y_train, x_test, y_test = self._split()
        y_train, y_test = y_train.astype(np.float64), y_test.astype(np.float64)
        results = {}
        for name in self.models:
            predicted = _regressor(name, self.seed).fit(x_train, y_train).predict(x_test)
            error = predicted - y_test
            results[name] = RegressionScores(
                mae=float(np.mean(np.abs(error))),
                rmse=float(np.sqrt(np.mean(error**2))),
                r2=float(r2_score(y_test, predicted)),
                n_train=len(y_train),
                n_test=len(y_test),
            )
        return results
