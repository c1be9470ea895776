"""``model.hysteresis=auto``: the hysteresis cell read off the training data (the grey-box's
cell, and the cell ``model=linear`` puts on its input with ``effects=[hysteresis]``).

A cheap test before any training (`cell_evidence`, a second or two on one core): the
grey-box's linear chain (amplifier lag, delay, modes: `select_chain_structure` on the
training recording, the structure the model starts from anyway) carries, beside its input,

* play operators of the input at thresholds spread over its range (`PLAY_OPERATORS` of
  them, `spread_over`, as the model's cell starts: a Prandtl–Ishlinskii cell), or
* one Bouc–Wen state of the input (exponent 1), the best shape of a grid (`BOUC_WEN_RATES`,
  `BOUC_WEN_RATIOS`),

each column through each mode, the weights by linear least squares, the chain's amplifier and
modes refined for each cell by `scipy.optimize.least_squares`. Both are scored on held-out
data (the validation recording; without one, the training recording's last fifth): the mean
square misfit of the output over its standard deviation. Where one cell's misfit is below
`CLEAR_RATIO` of the other's and of the chain alone's, the test decides; where it is not,
the data leave the choice open and both cells are fitted, the lower validation free-run loss
kept (`hysteresis_lab.workflows.grow`): a near tie of the test, or a cell that barely improves
on the chain alone (a chain the best linear approximation misread), says little about which
cell the free-run training takes further.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import signal
from scipy.optimize import least_squares

from hysteresis_lab.blocks import bouc_wen_free_run
from hysteresis_lab.blocks.estimate import (
    DAMPING_RANGE,
    ChainStructure,
    select_chain_structure,
)
from hysteresis_lab.physics.filters import mode_coefficients_np
from hysteresis_lab.physics.play import play_operators, spread_over

if TYPE_CHECKING:
    from hysteresis_lab.data.recording import Recording

log = logging.getLogger(__name__)

#: the cells ``model.hysteresis=auto`` chooses between
CELLS = ("bouc_wen", "prandtl_ishlinskii")
#: the test decides where one cell's held-out misfit is below this share of the other's and
#: of the chain alone's
CLEAR_RATIO = 0.8
#: play operators of the test, their thresholds spread over the input's range
PLAY_OPERATORS = 8
#: Bouc–Wen shapes of the test (input over its standard deviation, ``alpha d = 1``): the
#: rate ``beta`` and ``gamma / beta``
BOUC_WEN_RATES = (0.1, 0.3, 1.0, 3.0, 10.0, 30.0)
BOUC_WEN_RATIOS = (-0.8, -0.4, 0.0, 0.4, 0.8)
#: most samples of a recording the test reads, and evaluations of each chain refinement
TEST_SAMPLES = 40_000
REFINE_EVALUATIONS = 20
#: the share of the training recording held out when there is no validation recording
HELD_OUT_SHARE = 0.2


#: the structures chosen for the last few training recordings (`chain_structure`)
_CHOSEN: dict[tuple[Any, ...], ChainStructure] = {}
_CHOSEN_KEPT = 4


def chain_structure(
    u: np.ndarray, y: np.ndarray, fs: float, delay: int | None, n_modes: int | None
) -> ChainStructure:
    """`select_chain_structure` of a training recording, remembered for the process: the
    stages of a grown model and the fit at once (``model.grow=best``) start from the same
    recording and choose alike."""
    key = (hashlib.sha1(np.ascontiguousarray(u, dtype=float).tobytes()).hexdigest(),
           hashlib.sha1(np.ascontiguousarray(y, dtype=float).tobytes()).hexdigest(),
           float(fs), delay, n_modes)
    if key not in _CHOSEN:
        if len(_CHOSEN) >= _CHOSEN_KEPT:
            _CHOSEN.pop(next(iter(_CHOSEN)))
        _CHOSEN[key] = select_chain_structure(u, y, fs, delay=delay, n_modes=n_modes,
                                              fmin=min(50.0, 0.01 * fs))
    return _CHOSEN[key]


@dataclass(frozen=True)
class CellEvidence:
    """What the data test found: the held-out mean square misfit (output over its standard
    deviation) of the chain alone (``none``) and with each cell, and the Bouc–Wen shape
    (``beta``, ``gamma / beta``) that fitted best."""

    misfits: dict[str, float]
    bouc_wen_shape: tuple[float, float]

    @property
    def ratio(self) -> float:
        """Bouc–Wen's misfit over Prandtl–Ishlinskii's (below 1: Bouc–Wen fits better)."""
        return self.misfits["bouc_wen"] / max(self.misfits["prandtl_ishlinskii"], 1e-300)

    @property
    def decided(self) -> str | None:
        """The cell the test chooses, or None where it leaves it open: the cell whose
        misfit is below `CLEAR_RATIO` of the other's and of the chain alone's (a cell that
        barely improves on the chain says little about which cell the plant has)."""
        cell = self.lower
        other = "prandtl_ishlinskii" if cell == "bouc_wen" else "bouc_wen"
        clear = CLEAR_RATIO * min(self.misfits[other], self.misfits["none"])
        return cell if self.misfits[cell] < clear else None

    @property
    def lower(self) -> str:
        """The cell with the lower held-out misfit."""
        return "bouc_wen" if self.ratio < 1.0 else "prandtl_ishlinskii"

    def to_dict(self) -> dict[str, Any]:
        return {"held_out_misfit": {k: float(v) for k, v in self.misfits.items()},
                "bouc_wen_over_prandtl_ishlinskii": float(self.ratio),
                "clear_ratio": CLEAR_RATIO,
                "bouc_wen_shape": {"beta": self.bouc_wen_shape[0],
                                   "gamma_over_beta": self.bouc_wen_shape[1]}}


def cell_evidence(
    u: np.ndarray, y: np.ndarray, fs: float, structure: ChainStructure,
    u_val: np.ndarray | None = None, y_val: np.ndarray | None = None,
) -> CellEvidence:
    """The data test of the module docstring on a training recording ``u -> y`` (1-D,
    physical units) and held-out ``u_val -> y_val`` (None: the training recording's last
    `HELD_OUT_SHARE`), with the linear ``structure`` read off the training data."""
    u = np.asarray(u, dtype=float).reshape(-1)
    y = np.asarray(y, dtype=float).reshape(-1)
    if u_val is None or y_val is None or len(u_val) < 100:
        cut = int(len(u) * (1.0 - HELD_OUT_SHARE))
        u, y, u_val, y_val = u[:cut], y[:cut], u[cut:], y[cut:]
    u_val = np.asarray(u_val, dtype=float).reshape(-1)[:TEST_SAMPLES]
    y_val = np.asarray(y_val, dtype=float).reshape(-1)[:TEST_SAMPLES]
    u, y = u[:TEST_SAMPLES], y[:TEST_SAMPLES]
    u_mean, u_std = float(np.mean(u)), max(float(np.std(u)), 1e-12)
    y_mean, y_std = float(np.mean(y)), max(float(np.std(y)), 1e-12)
    v, v_val = (u - u_mean) / u_std, (u_val - u_mean) / u_std
    target, target_val = (y - y_mean) / y_std, (y_val - y_mean) / y_std
    theta = np.r_[np.log(structure.amplifier_hz),
                  np.ravel(np.c_[np.log(structure.frequencies_hz), np.log(structure.dampings)])]
    chain = _Chain(fs, structure.delay, theta)

    def score(cell: np.ndarray, cell_val: np.ndarray, refine: bool = True) -> float:
        return chain.held_out_misfit(cell, target, cell_val, target_val, refine)

    misfits = {"none": score(v[:, None], v_val[:, None])}
    thresholds = spread_over(v, PLAY_OPERATORS)
    misfits["prandtl_ishlinskii"] = score(np.c_[v, play_operators(v, thresholds)],
                                          np.c_[v_val, play_operators(v_val, thresholds)])

    def bouc_wen_state(x: np.ndarray, beta: float, ratio: float) -> np.ndarray:
        return np.c_[x, bouc_wen_free_run(x[None], 1.0, 1.0, beta, ratio * beta)[0]]

    shapes = [(beta, ratio) for beta in BOUC_WEN_RATES for ratio in BOUC_WEN_RATIOS]
    shape = min(shapes, key=lambda s: score(bouc_wen_state(v, *s), bouc_wen_state(v_val, *s),
                                            refine=False))
    misfits["bouc_wen"] = score(bouc_wen_state(v, *shape), bouc_wen_state(v_val, *shape))
    return CellEvidence(misfits, (float(shape[0]), float(shape[1])))


class _Chain:
    """The grey-box's linear chain at ``delay`` samples, its amplifier cutoff and modes
    ``theta = [log f_c, log f_1, log zeta_1, ...]``, carrying cell columns."""

    def __init__(self, fs: float, delay: int, theta: np.ndarray) -> None:
        self.fs, self.delay = fs, int(delay)
        n_modes = (len(theta) - 1) // 2
        self.lower = np.r_[np.log(0.01 * fs),
                           [np.log(1e-3 * fs), np.log(DAMPING_RANGE[0])] * n_modes]
        self.upper = np.r_[np.log(0.45 * fs),
                           [np.log(0.44 * fs), np.log(DAMPING_RANGE[1])] * n_modes]
        self.theta = np.clip(theta, self.lower + 1e-9, self.upper - 1e-9)

    def design(self, cell: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """The regressors: each cell column through the amplifier, the delay and each mode,
        and a constant."""
        pole = np.exp(-2.0 * np.pi * np.exp(theta[0]) / self.fs)
        z = signal.lfilter([1.0 - pole], [1.0, -pole], cell, axis=0)
        z = np.vstack([np.zeros((self.delay, z.shape[1])), z[: len(z) - self.delay]])
        columns = [signal.lfilter(*mode_coefficients_np(np.exp(theta[1 + 2 * m]),
                                                        np.exp(theta[2 + 2 * m]), self.fs),
                                  z, axis=0)
                   for m in range((len(theta) - 1) // 2)]
        return np.hstack([*columns, np.ones((len(z), 1))])

    def held_out_misfit(self, cell: np.ndarray, target: np.ndarray, cell_val: np.ndarray,
                        target_val: np.ndarray, refine: bool) -> float:
        """Weights (and with ``refine`` the chain) fitted on ``cell -> target``, the mean
        square misfit on ``cell_val -> target_val``."""

        def residuals(theta: np.ndarray) -> np.ndarray:
            a = self.design(cell, theta)
            coef, *_ = np.linalg.lstsq(a, target, rcond=None)
            return a @ coef - target

        theta = self.theta
        if refine:
            try:
                theta = least_squares(residuals, theta, bounds=(self.lower, self.upper),
                                      max_nfev=REFINE_EVALUATIONS).x
            except (ValueError, np.linalg.LinAlgError):  # pragma: no cover - degenerate data
                theta = self.theta
        coef, *_ = np.linalg.lstsq(self.design(cell, theta), target, rcond=None)
        misfit = float(np.mean((self.design(cell_val, theta) @ coef - target_val) ** 2))
        return misfit if np.isfinite(misfit) else np.inf


def cells_from_data(
    train: Recording, val: Recording | None, delay: int | None = None,
    n_modes: int | None = None,
) -> tuple[list[str], dict[str, Any]]:
    """``auto``'s cells on one-axis recordings: the one the data test decides, or both where
    it leaves the choice open (or cannot read the data); and what it found (for
    ``metrics.json``). ``delay`` / ``n_modes``: the chain's, None to read them off the data."""
    try:
        structure = chain_structure(train.u[:, 0], train.y[:, 0], train.fs, delay, n_modes)
        evidence = cell_evidence(train.u[:, 0], train.y[:, 0], train.fs, structure,
                                 None if val is None else val.u[:, 0],
                                 None if val is None else val.y[:, 0])
    except ValueError as exc:  # e.g. too few samples for the linear chain's spectra
        why = f"the training data could not be read for the data test ({exc})"
        log.info("hysteresis=auto: %s; both cells are fitted", why)
        return list(CELLS), {"by": "validation free-run loss", "data_test": why}
    found = evidence.to_dict()
    if evidence.decided is not None:
        log.info("hysteresis=auto: %s, by the data test (held-out misfit Bouc–Wen %.4g, "
                 "Prandtl–Ishlinskii %.4g, chain alone %.4g: ratio %.3g)", evidence.decided,
                 evidence.misfits["bouc_wen"], evidence.misfits["prandtl_ishlinskii"],
                 evidence.misfits["none"], evidence.ratio)
        return [evidence.decided], {"chosen": evidence.decided, "by": "data test", **found}
    log.info("hysteresis=auto: the data test leaves the cell open (held-out misfit Bouc–Wen "
             "%.4g, Prandtl–Ishlinskii %.4g, chain alone %.4g: the lower not below %.3g of "
             "the others): both cells are fitted, the lower validation free-run loss kept",
             evidence.misfits["bouc_wen"], evidence.misfits["prandtl_ishlinskii"],
             evidence.misfits["none"], CLEAR_RATIO)
    return list(CELLS), {"by": "validation free-run loss", **found}
