"""A zoo of positioners: random plants of the simulator's physics class, drawn from a
documented prior (`ZooPrior`) and reproducible from a seed.

A drawn plant is a `hysteresis_lab.sim.config.PositionerConfig` (its blocks in signal order:
``draw_plant(seed).chain()``), the same effect blocks the models grow, or the mapping
``data.effects`` takes (`draw_effects`). The bundled default positioner is one point of the
prior (`outside_prior` finds nothing outside it). `export_zoo_plant` writes the study's
recordings of a drawn plant to CSV for ``data=csv``; from the command line::

    python -m hysteresis_lab.sim.zoo --seed 7 --out zoo_7     # the study's recordings as CSV
    hysteresis-lab-simulate zoo_seed=7 output=zoo_7.csv       # one recording of plant 7

The prior is described in ``docs/zoo.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hysteresis_lab.sim.blocks import NOMINAL_STROKE_UM
from hysteresis_lab.sim.config import PositionerConfig

log = logging.getLogger(__name__)

#: the drive amplitude (V) of the study's recordings; the hysteresis thresholds and the
#: asymmetry are drawn relative to it
DRIVE_V = 100.0
#: blocks no zoo plant switches on (the effects the loop issue adds to zoo plants in turn)
OFF_BLOCKS = ("saturation", "dead_zone", "backlash", "rate_dependence", "drift", "output_delay")
MODE_KEYS = ("mode1", "mode2", "mode3")

Range = tuple[float, float]


@dataclass(frozen=True)
class ZooPrior:
    """Ranges of a zoo plant's parameters; "log" ranges are drawn log-uniformly, the others
    uniformly, each independently unless said otherwise.

    Hysteresis cell: Prandtl–Ishlinskii with probability ``pi_probability``, else Bouc–Wen.
    Bouc–Wen (``x = d v - h``): ``alpha`` in ``bw_alpha``, capped at 0.9 of its passivity
    bound ``(1 + gamma/beta) / 2`` (above it the displacement would move against the drive
    right after a reversal); the rates' ratio ``gamma / beta`` in ``bw_rate_ratio`` (both
    signs: the two rates ``beta -/+ gamma`` in any ratio); exponent ``n`` in ``bw_exponent``;
    the saturated state ``alpha d V_s`` set by the drive ``V_s`` in ``bw_saturation_v`` (log;
    ``1 / (beta + gamma)`` at ``n = 1``). Prandtl–Ishlinskii: a count of plays in
    ``pi_plays``, their thresholds uniform in ``pi_threshold_v`` and sorted (so unevenly
    spaced), their weights a flat Dirichlet split of a share in ``pi_share``. Asymmetric loop
    with probability ``asymmetry_probability``: the square law's rise at full drive a share
    in ``asymmetry_share`` of the stroke ``2 d DRIVE_V`` (either sign).

    Linear part: ``d`` in ``gain_um_per_v`` (log); modes: a count in ``modes``, frequencies
    in ``mode_hz`` (log, sorted), dampings in ``damping`` (log), each later mode's share of
    the gain in ``mode_weight``; the amplifier's pole in ``amplifier_hz`` (log); an input
    delay in ``delay_samples``; creep with probability ``creep_probability``, its weight per
    decade in ``creep_per_decade``; sensor noise in ``noise_um`` (log), quantisation fixed.
    """

    gain_um_per_v: Range = (0.05, 1.0)
    pi_probability: float = 0.3
    bw_alpha: Range = (0.05, 0.6)
    bw_rate_ratio: Range = (-0.95, 0.95)
    bw_exponent: Range = (1.0, 3.0)
    bw_saturation_v: Range = (10.0, 200.0)
    pi_plays: tuple[int, int] = (2, 10)
    pi_threshold_v: Range = (1.0, 90.0)
    pi_share: Range = (0.05, 0.5)
    asymmetry_probability: float = 0.5
    asymmetry_share: Range = (-0.05, 0.05)
    modes: tuple[int, int] = (1, 3)
    mode_hz: Range = (300.0, 5000.0)
    damping: Range = (0.005, 0.1)
    mode_weight: Range = (0.02, 0.3)
    amplifier_hz: Range = (1000.0, 20000.0)
    delay_samples: tuple[int, int] = (0, 5)
    creep_probability: float = 0.5
    creep_per_decade: Range = (0.005, 0.03)
    noise_um: Range = (0.003, 0.05)
    quantisation_um: float = 0.001

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def _log_uniform(rng: np.random.Generator, bounds: Range) -> float:
    return float(math.exp(rng.uniform(math.log(bounds[0]), math.log(bounds[1]))))


def _uniform(rng: np.random.Generator, bounds: Range) -> float:
    return float(rng.uniform(bounds[0], bounds[1]))


def bouc_wen_passivity_bound(rate_ratio: float) -> float:
    """The largest ``alpha`` with which a Bouc–Wen displacement never moves against the drive:
    ``(beta + gamma) / 2 beta`` (the state's slope against its sign reaches
    ``alpha d (1 + (beta - gamma) / (beta + gamma))`` at saturation)."""
    return (1.0 + rate_ratio) / 2.0


def _hysteresis(rng: np.random.Generator, prior: ZooPrior, d: float) -> dict[str, Any]:
    if rng.uniform() < prior.pi_probability:
        count = int(rng.integers(prior.pi_plays[0], prior.pi_plays[1] + 1))
        thresholds = np.sort(rng.uniform(*prior.pi_threshold_v, size=count))
        weights = rng.dirichlet(np.ones(count)) * _uniform(rng, prior.pi_share)
        return {"enabled": True, "cell": "prandtl_ishlinskii", "d_um_per_v": d,
                "thresholds_v": [float(r) for r in thresholds],
                "weights": [float(w) for w in weights]}
    ratio = _uniform(rng, prior.bw_rate_ratio)
    alpha = min(_uniform(rng, prior.bw_alpha), 0.9 * bouc_wen_passivity_bound(ratio))
    exponent = _uniform(rng, prior.bw_exponent)
    saturation_v = _log_uniform(rng, prior.bw_saturation_v)
    h_sat = alpha * d * saturation_v
    rate = alpha * d / h_sat**exponent  # beta + gamma: the state saturates at h_sat
    beta = rate / (1.0 + ratio)
    return {"enabled": True, "cell": "bouc_wen", "d_um_per_v": d, "alpha": alpha,
            "beta": beta, "gamma": ratio * beta, "exponent": exponent}


def _modes(rng: np.random.Generator, prior: ZooPrior) -> dict[str, Any]:
    count = int(rng.integers(prior.modes[0], prior.modes[1] + 1))
    frequencies = np.sort([_log_uniform(rng, prior.mode_hz) for _ in range(count)])
    blocks: dict[str, Any] = {}
    for i, key in enumerate(MODE_KEYS):
        if i < count:
            blocks[key] = {"enabled": True, "frequency_hz": float(frequencies[i]),
                           "damping": _log_uniform(rng, prior.damping),
                           "weight": 1.0 if i == 0 else _uniform(rng, prior.mode_weight)}
        else:
            blocks[key] = {"enabled": False}
    return blocks


def draw_effects(seed: int, prior: ZooPrior | None = None) -> dict[str, Any]:
    """Plant ``seed`` of the zoo as the mapping ``data.effects`` takes (every block named:
    the drawn ones on, the others off)."""
    prior = prior or ZooPrior()
    rng = np.random.default_rng([int(seed), 0x200])  # the zoo's own stream of the seed
    d = _log_uniform(rng, prior.gain_um_per_v)
    effects: dict[str, Any] = {"hysteresis": _hysteresis(rng, prior, d)}
    asymmetric = rng.uniform() < prior.asymmetry_probability
    share = _uniform(rng, prior.asymmetry_share)
    effects["asymmetry"] = {
        "enabled": bool(asymmetric), "v_ref": DRIVE_V,
        "coefficient": share * 2.0 * d * DRIVE_V / NOMINAL_STROKE_UM if asymmetric else 0.0}
    effects.update(_modes(rng, prior))
    effects["amplifier"] = {"enabled": True, "cutoff_hz": _log_uniform(rng, prior.amplifier_hz)}
    effects["input_delay"] = {
        "enabled": True,
        "samples": int(rng.integers(prior.delay_samples[0], prior.delay_samples[1] + 1))}
    creep = rng.uniform() < prior.creep_probability
    effects["creep"] = {"enabled": bool(creep),
                        "weight_per_decade": _uniform(rng, prior.creep_per_decade)}
    effects["noise"] = {"enabled": True, "rms_um": _log_uniform(rng, prior.noise_um)}
    effects["quantisation"] = {"enabled": True, "step_um": prior.quantisation_um}
    effects.update({key: {"enabled": False} for key in OFF_BLOCKS})
    return effects


def draw_plant(seed: int, prior: ZooPrior | None = None) -> PositionerConfig:
    """Plant ``seed`` of the zoo: its blocks and parameters (``.chain()``: in signal order)."""
    return PositionerConfig.from_dict(draw_effects(seed, prior))


def _inside(name: str, value: float, bounds: Range, problems: list[str]) -> None:
    low, high = bounds
    if not low * (1 - 1e-9) <= value <= high * (1 + 1e-9):
        problems.append(f"{name}={value:.6g} outside [{low:g}, {high:g}]")


def outside_prior(config: PositionerConfig, prior: ZooPrior | None = None) -> list[str]:
    """The parameters of ``config`` that lie outside ``prior`` (empty: the plant is one of
    its points), read back in the prior's own terms."""
    prior = prior or ZooPrior()
    c, problems = config, []
    h = c.hysteresis
    if not h.enabled:
        problems.append("hysteresis is off (every zoo plant has a cell)")
    _inside("hysteresis.d_um_per_v", h.d_um_per_v, prior.gain_um_per_v, problems)
    if h.cell == "prandtl_ishlinskii":
        _inside("number of plays", len(h.thresholds_v), prior.pi_plays, problems)
        for r in h.thresholds_v:
            _inside("play threshold (V)", r, prior.pi_threshold_v, problems)
        _inside("plays' share", sum(h.weights), prior.pi_share, problems)
    else:
        ratio = h.gamma / h.beta
        _inside("gamma / beta", ratio, prior.bw_rate_ratio, problems)
        _inside("alpha", h.alpha, (0.0, prior.bw_alpha[1]), problems)
        _inside("alpha", h.alpha, (0.0, 0.9 * bouc_wen_passivity_bound(ratio)), problems)
        _inside("exponent", h.exponent, prior.bw_exponent, problems)
        h_sat = (h.alpha * h.d_um_per_v / (h.beta + h.gamma)) ** (1.0 / h.exponent)
        _inside("saturation drive (V)", h_sat / (h.alpha * h.d_um_per_v),
                prior.bw_saturation_v, problems)
    if c.asymmetry.enabled:
        share = c.asymmetry.coefficient * NOMINAL_STROKE_UM / (2.0 * h.d_um_per_v * DRIVE_V)
        _inside("asymmetry share", share * (DRIVE_V / c.asymmetry.v_ref) ** 2,
                prior.asymmetry_share, problems)
    modes = [getattr(c, key) for key in MODE_KEYS]
    if not modes[0].enabled:
        problems.append("mode1 is off (the first mode turns the displacement into the output)")
    on = [m for m in modes if m.enabled]
    _inside("number of modes", len(on), prior.modes, problems)
    for i, m in enumerate(on):
        _inside(f"mode {i + 1} frequency (Hz)", m.frequency_hz, prior.mode_hz, problems)
        _inside(f"mode {i + 1} damping", m.damping, prior.damping, problems)
        if i:
            _inside(f"mode {i + 1} weight", m.weight, prior.mode_weight, problems)
    if not c.amplifier.enabled:
        problems.append("the amplifier is off")
    _inside("amplifier pole (Hz)", c.amplifier.cutoff_hz, prior.amplifier_hz, problems)
    _inside("input delay (samples)", c.input_delay.samples if c.input_delay.enabled else 0,
            prior.delay_samples, problems)
    if c.creep.enabled:
        _inside("creep per decade", c.creep.weight_per_decade, prior.creep_per_decade, problems)
    _inside("noise (um)", c.noise.rms_um if c.noise.enabled else 0.0, prior.noise_um, problems)
    if not (c.quantisation.enabled and c.quantisation.step_um == prior.quantisation_um):
        problems.append(f"quantisation is not {prior.quantisation_um} um")
    problems += [f"{key} is on (no zoo plant has it)" for key in OFF_BLOCKS
                 if getattr(c, key).enabled]
    return problems


def describe(config: PositionerConfig) -> dict[str, Any]:
    """The plant in the prior's terms: what a table of zoo results shows per plant."""
    c, h = config, config.hysteresis
    out: dict[str, Any] = {"d_um_per_v": h.d_um_per_v, "cell": h.cell}
    if h.cell == "prandtl_ishlinskii":
        out.update(plays=len(h.thresholds_v), pi_share=sum(h.weights))
    else:
        out.update(alpha=h.alpha, rate_ratio=h.gamma / h.beta, exponent=h.exponent)
    out["asymmetry"] = c.asymmetry.enabled
    out["modes_hz"] = [m.frequency_hz for m in (c.mode1, c.mode2, c.mode3) if m.enabled]
    out["dampings"] = [m.damping for m in (c.mode1, c.mode2, c.mode3) if m.enabled]
    out.update(amplifier_hz=c.amplifier.cutoff_hz,
               delay_samples=c.input_delay.samples if c.input_delay.enabled else 0,
               creep_per_decade=c.creep.weight_per_decade if c.creep.enabled else 0.0,
               noise_um=c.noise.rms_um)
    return out


def export_zoo_plant(seed: int, folder: str | Path, data_seed: int = 0,
                     prior: ZooPrior | None = None,
                     max_test_samples: int | None = None) -> dict[str, Any]:
    """Write plant ``seed``'s study recordings to ``folder`` as CSV (``t,u,y``; s, V, µm):
    ``train.csv`` (the 500-line multisine), ``val.csv`` (a second realisation, 20,000
    samples) and ``test_sine_<f>Hz.csv`` (the twelve ±100 V sines), with ``plant.json`` (the
    plant's ``data.effects`` and its description); ``max_test_samples`` cuts the sines
    short (quick checks). Returns the paths by role, for ``data=csv data.train=...
    data.val=... data.test=[...]``."""
    from hysteresis_lab.data.readers import write_csv
    from hysteresis_lab.sim.default_dataset import make_default_dataset

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    effects = draw_effects(seed, prior)
    splits = make_default_dataset(effects, seed=data_seed, val_samples=20_000,
                                  max_test_samples=max_test_samples)
    paths = {"train": str(write_csv(splits.train[0], folder / "train.csv")),
             "val": str(write_csv(splits.val[0], folder / "val.csv")),
             "test": [str(write_csv(rec, folder / f"test_{rec.name}.csv"))
                      for rec in splits.test]}
    plant = {"seed": seed, "data_seed": data_seed, "effects": effects,
             "description": describe(PositionerConfig.from_dict(effects)), "files": paths}
    (folder / "plant.json").write_text(json.dumps(plant, indent=1) + "\n")
    log.info("zoo plant %d: wrote %d recordings to %s", seed, 2 + len(paths["test"]), folder)
    return paths


def main(argv: Sequence[str] | None = None) -> None:
    """``python -m hysteresis_lab.sim.zoo --seed S --out FOLDER``."""
    parser = argparse.ArgumentParser(description=export_zoo_plant.__doc__)
    parser.add_argument("--seed", type=int, required=True, help="the plant's seed")
    parser.add_argument("--out", required=True, help="folder for the CSV files")
    parser.add_argument("--data-seed", type=int, default=0, help="phases and noise")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    paths = export_zoo_plant(args.seed, args.out, args.data_seed)
    log.info("fit it with: hysteresis-lab-train data=csv data.train=%s data.val=%s "
             "'data.test=[%s]'", paths["train"], paths["val"], ",".join(paths["test"]))


if __name__ == "__main__":
    main()
