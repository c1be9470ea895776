"""SVM baseline (scikit-learn) on the flat NARX regressor.

Exact kernel SVR costs O(n²) memory and O(n²)-O(n³) time in the number of windows (63,000
in the study's protocol), so two sound approximations are offered:

* ``strategy="nystroem"`` (default): a Nyström approximation of the kernel
  (``n_components`` landmark windows) followed by a linear SVR (`LinearSVR`) with the
  squared epsilon-insensitive loss, solved in the primal (a Newton method: ~15 s on the
  72,000 default windows, where liblinear's dual solver for the plain epsilon-insensitive
  loss needs many minutes); this keeps every training window and costs O(n · n_components).
* ``strategy="subsample"``: exact `SVR` with the chosen kernel on ``max_samples`` random
  windows.

The linear kernel always uses `LinearSVR` on all windows. Normalisation lives inside the
model (the same scaler as the networks). Saved with skops, never with pickle.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from sklearn.kernel_approximation import Nystroem
from sklearn.svm import SVR, LinearSVR

from hysteresis_lab.data.scaling import Scaler
from hysteresis_lab.data.windows import WindowSpec, assemble
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.kernels.interface import FlatKernel, FreeRunKernel
from hysteresis_lab.kernels.svm import SVMKernel
from hysteresis_lab.models.interface import EstimatorModel, ModelContract
from hysteresis_lab.models.settings import ModelSettings, refuse_output_effects, unknown_settings

log = logging.getLogger(__name__)

KERNELS = ("linear", "poly", "rbf", "sigmoid")
STRATEGIES = ("nystroem", "subsample")


class SVMModel(ModelContract, EstimatorModel):
    """Epsilon-SVR per output channel, with the scaler and lag structure of the data.

    Built as ``SVMModel(nu=, ny=, <its own settings>, **settings)``: the settings every model
    shares (`ModelSettings`: lags, scaler, effects, ``trained_on``) by name."""

    layout: ClassVar[str] = "flat"
    registry_name: ClassVar[str] = "svm"
    #: the shared settings it takes (`ModelContract.settings_keys`): no effect path, input
    #: block or baseline, no training settings (it is fitted in one call)
    shared_settings: ClassVar[tuple[str, ...]] = (
        "na", "nb", "nk", "scaler", "effects", "feature_context", "trained_on")

    def __init__(
        self,
        nu: int,
        ny: int,
        kernel: str = "rbf",
        C: float = 10.0,
        degree: int = 3,
        gamma: float = 0.1,
        coef0: float = 0.0,
        epsilon: float = 0.001,
        strategy: str = "nystroem",
        n_components: int = 1000,
        max_samples: int = 5000,
        seed: int = 0,
        **settings: Any,
    ) -> None:
        unknown_settings(settings, self.shared_settings, type(self).__name__)
        shared = ModelSettings.from_kwargs(nu, ny, settings)
        if kernel not in KERNELS:
            raise ConfigError(
                f"unknown SVM kernel '{kernel}'. Fix: model.kernel=one of {list(KERNELS)}."
            )
        if strategy not in STRATEGIES:
            raise ConfigError(
                f"unknown SVM strategy '{strategy}'. Fix: model.strategy=one of {list(STRATEGIES)}."
            )
        refuse_output_effects(shared.effects.effects, "the SVM")
        if C <= 0 or gamma <= 0 or degree < 1:
            raise ConfigError(
                f"SVM needs C > 0, gamma > 0 and degree >= 1 (got C={C}, gamma={gamma}, "
                f"degree={degree}). Fix: e.g. model.C=10 model.gamma=0.1 model.degree=3 (the "
                "study's search space: C 0.1-100, gamma 1e-4-10, degree 2-6)."
            )
        flat = shared.to_kwargs()
        self.hparams: dict[str, Any] = {
            **{k: flat[k] for k in ("nu", "ny", "na", "nb", "nk")},
            "kernel": kernel,
            "C": C,
            "degree": degree,
            "gamma": gamma,
            "coef0": coef0,
            "epsilon": epsilon,
            "strategy": strategy,
            "n_components": n_components,
            "max_samples": max_samples,
            "seed": seed,
            "effects": flat["effects"],
            "feature_context": flat["feature_context"],
            "model_name": "svm",
            "scaler": flat["scaler"],
            "trained_on": flat["trained_on"],
        }
        self.nu, self.ny = nu, ny
        self.window = shared.window
        scaler = shared.scaler
        self.scaler = (
            Scaler.from_dict(scaler)
            if scaler
            else Scaler(np.zeros(nu), np.ones(nu), np.zeros(ny), np.ones(ny))
        )
        self.feature_map: Nystroem | None = None
        self.estimators: list[Any] = []

    # ------------------------------------------------------------------ fitting
    def fit(self, x: np.ndarray, target: np.ndarray) -> SVMModel:
        """Fit on scaled flat regressors ``x`` (M, n) and scaled targets (M, ny)."""
        h = self.hparams
        rng = np.random.default_rng(h["seed"])
        if h["kernel"] == "linear" or h["strategy"] == "nystroem":
            if h["kernel"] != "linear":
                self.feature_map = Nystroem(
                    kernel=h["kernel"],
                    gamma=h["gamma"],
                    degree=h["degree"],
                    coef0=h["coef0"],
                    n_components=min(h["n_components"], len(x)),
                    random_state=h["seed"],
                ).fit(x)
            features = self._features(x)
            log.info(
                "SVM: linear SVR on %d windows x %d features, one fit per output (%d); the cost "
                "grows faster than the window count (on large data a lower model.n_components "
                "or model.strategy=subsample is faster)",
                *features.shape,
                target.shape[1],
            )
            self.estimators = []
            for j in range(target.shape[1]):
                start = time.perf_counter()
                self.estimators.append(
                    LinearSVR(
                        C=h["C"],
                        epsilon=h["epsilon"],
                        loss="squared_epsilon_insensitive",
                        dual=False,  # primal Newton solver: seconds where the dual needs minutes
                        max_iter=5000,
                        random_state=h["seed"],
                    ).fit(features, target[:, j])
                )
                log.info("SVM output %d fitted in %.1f s", j, time.perf_counter() - start)
        else:
            rows = rng.choice(len(x), size=min(h["max_samples"], len(x)), replace=False)
            self.estimators = [
                SVR(
                    kernel=h["kernel"],
                    C=h["C"],
                    epsilon=h["epsilon"],
                    gamma=h["gamma"],
                    degree=h["degree"],
                    coef0=h["coef0"],
                ).fit(x[rows], target[rows, j])
                for j in range(target.shape[1])
            ]
        log.info("SVM (%s kernel, %s) fitted on %d windows", h["kernel"], h["strategy"], len(x))
        return self

    def _features(self, x: np.ndarray) -> np.ndarray:
        return self.feature_map.transform(x) if self.feature_map is not None else x

    # ------------------------------------------------------------------ prediction
    def predict_scaled(self, x: np.ndarray) -> np.ndarray:
        features = self._features(np.asarray(x, dtype=np.float64))
        return np.column_stack([est.predict(features) for est in self.estimators])

    def predict_physical(self, u_past: np.ndarray, y_past: np.ndarray) -> np.ndarray:
        """Physical lags (B, nb, nu), (B, na, ny) -> physical next output (B, ny)."""
        s = self.scaler
        x = assemble((u_past - s.u_offset) / s.u_scale, (y_past - s.y_offset) / s.y_scale, "flat")
        return self.predict_scaled(x) * s.y_scale + s.y_offset

    def _folded(self) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
        """``(components, weights, bias)``: scaled prediction = k(x, components) @ weights + bias.

        Nyström + linear SVR folds to ``normalization_.T @ coef``; exact SVRs stack their
        support vectors (dual coefficients block-wise per output). ``components`` is None for
        the linear kernel (prediction = x @ weights + bias). All in float64: the fit sees
        float32 windows, and a float32 ``|c|^2`` in the expanded rbf of the free run is off by
        ~1e-4 (scaled) already at the first step.
        """
        bias = np.array([float(np.ravel(e.intercept_)[0]) for e in self.estimators])
        if self.feature_map is None and all(isinstance(e, LinearSVR) for e in self.estimators):
            return None, np.column_stack([e.coef_ for e in self.estimators]).astype(float), bias
        if self.feature_map is not None:
            fm = self.feature_map
            coef = np.column_stack([e.coef_ for e in self.estimators])
            components = fm.components_.astype(float)
            return components, fm.normalization_.T.astype(float) @ coef, bias
        comps = np.concatenate([e.support_vectors_ for e in self.estimators]).astype(float)
        weights = np.zeros((len(comps), len(self.estimators)))
        row = 0
        for j, est in enumerate(self.estimators):
            n_sv = len(est.support_vectors_)
            weights[row : row + n_sv, j] = est.dual_coef_[0]
            row += n_sv
        return comps, weights, bias

    def export_onnx(self, path: Path | str, opset: int = 17) -> Path:
        """Refused: an SVM is shared as its ``model.skops`` file."""
        raise ConfigError(
            f"{type(self).__name__} cannot be exported to ONNX here; only the networks can. "
            "Fix: share the SVM's model.skops file (load it with hysteresis_lab.models.io)."
        )

    def free_run_kernel(self, u_scaled: np.ndarray, window: WindowSpec) -> FreeRunKernel:
        """Free-run step with the model folded to one kernel evaluation per step (NumPy
        ``step``; compiled ``run_all`` for the non-linear kernels)."""
        if not self.estimators:
            raise ConfigError("the SVM is not fitted yet. Fix: call fit() (or train) first.")
        comps, weights, bias = self._folded()
        split = window.nb * self.nu
        if comps is None:
            wu, wy = weights[:split], weights[split:]
            return FlatKernel(
                u_scaled, window, lambda xu: xu @ wu + bias, lambda pre, xy: pre + xy @ wy
            )
        h = self.hparams
        kernel, gamma, degree, coef0 = h["kernel"], h["gamma"], h["degree"], h["coef0"]
        cu, cy = comps[:, :split].T.copy(), comps[:, split:].T.copy()
        comp_sq = np.sum(comps**2, axis=1)
        if kernel == "rbf":
            # exp(-g|x-c|^2) = exp(2g (x.c - |x|^2/2) - g|c|^2), split into u and y parts
            def pre_u(xu: np.ndarray) -> np.ndarray:
                return xu @ cu - 0.5 * np.sum(xu**2, axis=1)[:, None]

            def finish(pre: np.ndarray, xy: np.ndarray) -> np.ndarray:
                lin = pre + xy @ cy
                lin -= 0.5 * np.sum(xy**2, axis=1)[:, None]
                return np.exp(2.0 * gamma * lin - gamma * comp_sq) @ weights + bias

        else:
            outer = np.tanh if kernel == "sigmoid" else (lambda z: z**degree)

            def pre_u(xu: np.ndarray) -> np.ndarray:
                return gamma * (xu @ cu) + coef0

            def finish(pre: np.ndarray, xy: np.ndarray) -> np.ndarray:
                return outer(pre + gamma * (xy @ cy)) @ weights + bias

        return SVMKernel(u_scaled, window, pre_u, finish, kernel, cy, weights, bias, gamma,
                         degree, comp_sq)
