"""Why the loop's saturation refit falls short of its ceiling (issue #23 item 4).

    python experiments/undeclared_effects.py --cases saturation --root /tmp/ue   # the loop run
    python experiments/saturation_refit.py --run /tmp/ue/saturation              # this study

On the loop run of the undeclared-effect case ``saturation`` (the simulator's amplifier
clips at ±``limit_v`` behind its 5 kHz low-pass; the start is ``model=linear effects=[]``)
this measures, on the run's own data:

* excitation: how much of each recording's amplifier output passes the clip level;
* placement: the simulator clips behind the amplifier's low-pass, the model's block ahead of
  all its dynamics; the RMS output difference of the two placements on the test sines;
* the round-0 model on test inputs clipped at the true level (a perfect block, the round-0
  dynamics unchanged) and the dynamics' gain beside the simulator's, in and beyond the
  multisine's 0-500 Hz band (a clipped sine's corners reach far beyond it);
* refits from the round-0 model as the loop runs them (whole refit, ``training.refit_lr`` =
  ``training.lr``), the block's weight and level free, fixed at the simulator's clip (weight 1,
  level ``limit_v``), one of them fixed, and a block-only refit;
* with ``--order3``: the loop again with ``model.order=3`` (the simulator's own order: the
  amplifier pole and the bending mode), nothing else changed;
* with ``--sm-start``: the loop again with the Steiglitz–McBride (output-error) start wherever
  it simulates the training records better than ARX (``OUTPUT_ERROR_REPLACES_AT = 1``, set in
  the loop's process), judged by the rule against its own round 0 and ceiling;
* with ``--starts``: on the simulator's cases and the measured benchmarks, the ARX and
  Steiglitz–McBride starts' gain at Nyquist over their static gain (a sampled physical
  low-pass system has far less than 1), their free-run error ratio and slowest-mode ratio:
  where a start rule keyed on that gain would change the start.

The page goes to ``docs/results/saturation_refit.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import logging
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lightning.pytorch.callbacks import Callback
from omegaconf import OmegaConf
from scipy import signal

from hysteresis_lab.blocks.sections import nyquist_share, slowest_rate, steiglitz_mcbride
from hysteresis_lab.cli.loop import run_fresh_loop
from hysteresis_lab.data.benchmarks import load_benchmark
from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.data.factory import build_splits
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.evaluation.provenance import commit_stamp
from hysteresis_lab.fitting import build_model
from hysteresis_lab.loop.checks import (
    ceiling,
    free_run_rmse,
    round_model,
    run_data_config,
)
from hysteresis_lab.loop.data import loop_data
from hysteresis_lab.loop.driver import LoopSettings
from hysteresis_lab.models.io import load_model
from hysteresis_lab.models.spec import ModelSpec
from hysteresis_lab.sim import blocks
from hysteresis_lab.sim.config import PositionerConfig
from hysteresis_lab.sim.default_dataset import make_default_dataset
from hysteresis_lab.sim.positioner import Positioner
from hysteresis_lab.workflows.pipeline import RunConfig, run_model

log = logging.getLogger("saturation_refit")

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "results" / "saturation_refit.md"
#: where the dynamics' gain is compared: in the multisine's band and beyond it
FREQUENCIES_HZ = (10.0, 100.0, 500.0, 900.0, 1500.0, 2500.0, 4500.0, 9000.0)
#: refits: tag -> (weight fixed at, level fixed at as a share of the clip, refit mode)
VARIANTS: dict[str, tuple[float | None, float | None, str]] = {
    "weight and level free (the loop's)": (None, None, "full"),
    "weight 1, level at the clip": (1.0, 1.0, "full"),
    "level at the clip, weight free": (None, 1.0, "full"),
    "weight 1, level free": (1.0, None, "full"),
    "block only, both free": (None, None, "new_inputs"),
}


@dataclasses.dataclass
class Study:
    """The loop run's data, settings and round-0 model."""

    run: Path
    data_cfg: dict[str, Any]
    cfg: Any
    fit_splits: Any
    tests: list[Recording]
    n_init: int
    start: Any

    @classmethod
    def load(cls, run: Path) -> Study:
        cfg = OmegaConf.load(run / ".hydra" / "config.yaml")
        data_cfg = run_data_config(run)
        splits = build_splits(data_cfg)
        settings = LoopSettings(**OmegaConf.to_container(cfg.loop, resolve=True))
        fit = loop_data(splits, DataSpec.from_config(cfg.data), settings.folds).fit
        return cls(run, data_cfg, cfg, fit, list(splits.test), splits.n_init,
                   load_model(run / "round_0" / "model.ckpt"))

    @property
    def limit_v(self) -> float:
        return float(self.data_cfg["effects"]["saturation"]["limit_v"])

    def positioner(self, **changes: Any) -> PositionerConfig:
        """The run's simulator without noise and quantisation, blocks changed as given."""
        quiet = {"noise": {"enabled": False}, "quantisation": {"enabled": False}}
        return PositionerConfig.from_dict({**self.data_cfg["effects"], **quiet, **changes})


def excitation(study: Study) -> list[dict[str, Any]]:
    """Per recording: samples whose amplifier output passes the clip, the excess's RMS."""
    amplifier = study.positioner().amplifier
    rows = []
    recordings = [*study.fit_splits.train, *study.fit_splits.val, *study.tests]
    for rec in recordings:
        v = blocks.amplifier(rec.u[:, 0], rec.fs, amplifier)
        excess = np.abs(v) - np.minimum(np.abs(v), study.limit_v)
        rows.append({"recording": rec.name, "samples": len(v),
                     "over_pct": 100 * float(np.mean(excess > 0)),
                     "excess_rms_v": float(np.sqrt(np.mean(excess**2)))})
    return rows


def placement(study: Study) -> dict[str, float]:
    """Per test: RMS of (clip behind the amplifier's low-pass) - (clip of the command)."""
    behind = Positioner(study.positioner())
    ahead = Positioner(study.positioner(saturation={"enabled": False}))
    limit = study.limit_v
    return {rec.name: float(np.sqrt(np.mean(
        (behind.simulate(rec.u[:, 0], rec.fs)
         - ahead.simulate(np.clip(rec.u[:, 0], -limit, limit), rec.fs)) ** 2)))
        for rec in study.tests}


def simulator_gain(study: Study, frequencies: np.ndarray, fs: float) -> np.ndarray:
    """|H| (um/V) of the simulator's linear chain: amplifier, gain, first mode, delays."""
    c = study.positioner()
    pole = np.exp(-2.0 * np.pi * c.amplifier.cutoff_hz / fs)
    _, h = signal.freqz([1.0 - pole], [1.0, -pole], worN=frequencies, fs=fs)
    wn = 2.0 * np.pi * c.mode1.frequency_hz
    warped = 2.0 * fs * np.tan(wn / (2.0 * fs))
    b, a = signal.bilinear([warped**2], [1.0, 2.0 * c.mode1.damping * warped, warped**2], fs)
    _, mode = signal.freqz(b, a, worN=frequencies, fs=fs)
    return np.abs(h * mode) * c.hysteresis.d_um_per_v


def model_gain(model: Any, frequencies: np.ndarray, fs: float) -> np.ndarray:
    """|H| (um/V) of a linear model's dynamics from input 0 to output 0."""
    b, a = (p.detach().cpu().numpy() for p in model.dynamics[0][0].polynomials())
    _, h = signal.freqz(np.ravel(b), a, worN=frequencies, fs=fs)
    return np.abs(h) * float(model.y_scale[0]) / float(model.u_scale[0])


def block_parameters(model: Any) -> tuple[float, float]:
    """The saturation block's weight and level (V)."""
    block = model.input_blocks[0]["saturation"]
    return float(block.weight.detach()), float(block.level.detach()) * float(model.u_scale[0])


class FixBlock(Callback):
    """Set the saturation block's weight and/or level at the fit's start and keep them."""

    def __init__(self, weight: float | None, level: float | None) -> None:
        self.weight, self.level = weight, level

    def on_fit_start(self, trainer: Any, pl_module: Any) -> None:
        block = pl_module.input_blocks[0]["saturation"]
        with torch.no_grad():
            if self.weight is not None:
                block.weight.fill_(self.weight)
                block.weight.requires_grad_(False)
            if self.level is not None:
                block.raw_level.fill_(float(np.log(self.level)))
                block.raw_level.requires_grad_(False)


def refit(study: Study, out: Path, weight: float | None, level_share: float | None,
          mode: str) -> tuple[Any, dict[str, float], float]:
    """A refit from the round-0 model at ``training.lr``: the model, test RMSE, val loss."""
    model_cfg = {**OmegaConf.to_container(study.cfg.model, resolve=True),
                 "effects": ["saturation"]}
    spec = ModelSpec.from_config(model_cfg)
    training = spec.training_settings(OmegaConf.to_container(study.cfg.training, resolve=True))
    level = None if level_share is None else level_share * study.limit_v / float(
        study.start.u_scale[0])
    config = RunConfig.build(
        spec, study.cfg.data, study.cfg.trainer, out, training.with_changes(refit_lr=training.lr),
        seed=int(study.cfg.seed), use_tensorboard=False, plots=False, refit=mode)
    result = run_model(config, splits=study.fit_splits, warm_start=study.start,
                       callbacks=[FixBlock(weight, level)])
    rmse = {k: v["rmse_free_run"] for k, v in result.document["tests"].items()}
    return result.model, rmse, float((result.refit_validation or {}).get("refit", np.nan))


def order3_loop(study: Study, out: Path) -> dict[str, Any]:
    """The loop run again with ``model.order=3``, nothing else changed: round 0's and the
    judged refit's test RMSE and the refit's model."""
    command = json.loads((study.run / "row.json").read_text())["command"].split()[1:]
    report, _ = run_fresh_loop([*command, "model.order=3"], out)
    rounds = report["rounds"]
    refit_round = next((r for r in rounds[1:] if not r.get("rejected")), rounds[1])
    return {"before": {t: m["rmse_free_run"] for t, m in rounds[0]["tests"].items()},
            "after": {t: m["rmse_free_run"] for t, m in refit_round["tests"].items()}}


#: the loop, its linear start taking the Steiglitz–McBride fit wherever it simulates better
SM_START_LOOP = ("import sys; import hysteresis_lab.models.linear as linear; "
                 "linear.OUTPUT_ERROR_REPLACES_AT = 1.0; "
                 "from hysteresis_lab.cli.loop import main; main()")
#: simulator data sets of the start check: the undeclared cases' blocks, hysteresis and creep off
START_CASES = {"saturation": "saturation", "dead_zone": "dead_zone", "backlash": "backlash",
               "mode2": "mode2", "creep": "creep", "linear (no effect)": None}
BENCHMARKS = ("cascaded_tanks", "fsm_piezo_mirror", "piezo_p885", "bouc_wen", "emps")


def rule_rows(run: Path) -> dict[str, dict[str, float]]:
    """Per test where clipping acts: round 0, the judged refit and the rule's bound (half
    the ceiling off round 0) of a loop run."""
    rounds = json.loads((run / "loop_report.json").read_text())["rounds"]
    after = next((r for r in rounds[1:] if not r.get("rejected")), rounds[1])
    rows: dict[str, dict[str, float]] = {"before": {}, "after": {}, "bound": {}}
    for row in ceiling(run, "saturation", 0):
        test = str(row["test"])
        if float(row["effect_size_um"]) > 0.05:
            rows["before"][test] = rounds[0]["tests"][test]["rmse_free_run"]
            rows["after"][test] = after["tests"][test]["rmse_free_run"]
            rows["bound"][test] = rows["before"][test] * (1 - float(row["max_cut_pct"]) / 200)
    return rows


def sm_start_loop(study: Study, out: Path) -> dict[str, dict[str, float]]:
    """The loop again, its start the Steiglitz–McBride fit wherever that simulates the
    training records better than ARX; its `rule_rows`."""
    command = json.loads((study.run / "row.json").read_text())["command"].split()[1:]
    subprocess.run([sys.executable, "-c", SM_START_LOOP, *command, f"hydra.run.dir={out}"],
                   check=True, capture_output=True, text=True)
    return rule_rows(out)


def start_fits(name: str, data: Any, scaling: str) -> list[dict[str, Any]]:
    """Per output: the linear start's ARX fit and the Steiglitz–McBride fit of
    ``model.order`` on ``data``'s training recordings."""
    datamodule = WindowDataModule(data, scaling=scaling)
    datamodule.setup()
    model = build_model({"name": "linear"}, datamodule, trained_on={"fs": data.train[0].fs})
    n = model.n_base_inputs
    vs = [np.asarray(r.u, float).reshape(len(r.u), -1)[:, :n] / model.u_scale[:n].numpy()
          for r in data.train]
    ys = [np.asarray(r.y, float).reshape(len(r.y), -1) / model.y_scale.numpy()
          for r in data.train]
    rows = []
    for o in range(model.ny):
        y_o = [y[:, o] for y in ys]
        error, order, b_arx, a_arx = model._arx_start(o, vs, y_o)
        full = model.hparams.order
        b, a = steiglitz_mcbride(vs, y_o, na=full, nb=model._nb(full), nk=model.hparams.delay)
        rows.append({"data": name, "output": o, "arx_order": order,
                     "arx_nyquist": nyquist_share(b_arx, a_arx), "sm_nyquist": nyquist_share(b, a),
                     "sm_error": model._set_start(o, vs, y_o, b, a) / error,
                     "sm_slowest": slowest_rate(a) / slowest_rate(a_arx)})
    return rows


def starts() -> list[dict[str, Any]]:
    """`start_fits` on the simulator's undeclared cases, its default data and the
    benchmarks."""
    quiet = {"hysteresis": {"enabled": False}, "creep": {"enabled": False}}
    rows = []
    for name, block in START_CASES.items():
        effects = {**quiet, **({block: {"enabled": True}} if block else {})}
        rows += start_fits(f"simulator: {name}", make_default_dataset(effects=effects,
                                                                      val_samples=20000), "paper")
    rows += start_fits("simulator: default (hysteresis, creep)",
                       make_default_dataset(val_samples=20000), "paper")
    for bench in BENCHMARKS:
        rows += start_fits(bench, load_benchmark(bench), "standard")
    return rows


def _cells(values: dict[str, float], keys: list[str] | None = None) -> str:
    """Table cells of ``values`` (in the order of ``keys`` when given, '–' where missing)."""
    keys = list(values) if keys is None else keys
    return " | ".join(f"{values[k]:.3f}" if k in values else "–" for k in keys)


def page(study: Study, parts: dict[str, Any], command: str) -> str:
    """The markdown page of the measurements."""
    tests = [rec.name for rec in study.tests]
    row = json.loads((study.run / "row.json").read_text())
    head = "| | " + " | ".join(t.replace("sine_", "") for t in tests) + " |\n|---|" + \
        "---|" * len(tests) + "\n"
    need = {t: row["before"][t] * (1 - row["ceiling_pct"][t] / 200) for t in tests
            if t in row["ceiling_pct"]}
    lines = [
        "# The saturation refit against its ceiling (issue #23 item 4)", "",
        f"Written by `{command}` at {commit_stamp(REPO)}, "
        f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC, on the loop run that "
        "`python experiments/undeclared_effects.py --cases saturation --root <root>` made, "
        f"`{row['command']}` (commit {row['commit']}). Simulator clip at "
        f"±{study.limit_v:g} V behind the amplifier's low-pass; the start `model=linear "
        "effects=[]`; free-run RMSE in µm on the test sines.", "",
        "## Excitation: amplifier output past the clip", "",
        "| recording | samples | past the clip | excess RMS (V) |", "|---|---|---|---|",
        *[f"| {r['recording']} | {r['samples']} | {r['over_pct']:.3f} % | "
          f"{r['excess_rms_v']:.3f} |" for r in parts["excitation"]], "",
        "## Test RMSE (µm)", "", head.rstrip("\n"),
        f"| round 0 (loop) | {_cells(row['before'])} |",
        f"| loop's refit | {_cells(row['after'])} |",
        f"| the rule: at most (half the ceiling off round 0) | {_cells(need, tests)} |",
        f"| placement: clip behind vs ahead of the amplifier (output RMS difference) | "
        f"{_cells(parts['placement'])} |",
        f"| round 0, test inputs clipped at {study.limit_v:g} V | {_cells(parts['clipped'])} |",
    ]
    for tag, (w, c, loss, rmse) in parts["refits"].items():
        lines.append(f"| refit: {tag} (w {w:.2f}, c {c:.1f} V, validation {loss:.3g}) | "
                     f"{_cells(rmse)} |")
    if "order3" in parts:
        lines += [f"| `model.order=3`: round 0 | {_cells(parts['order3']['before'])} |",
                  f"| `model.order=3`: the loop's refit | {_cells(parts['order3']['after'])} |"]
    if "sm_start" in parts:
        sm = parts["sm_start"]
        lines += [f"| Steiglitz–McBride start: round 0 | {_cells(sm['before'], tests)} |",
                  f"| Steiglitz–McBride start: the loop's refit | {_cells(sm['after'], tests)} |",
                  f"| Steiglitz–McBride start: the rule's bound | {_cells(sm['bound'], tests)} |"]
    freqs = parts["frequencies"]
    lines += ["", "## Gain of the dynamics (µm/V), in and beyond the multisine's band", "",
              "| | " + " | ".join(f"{f:g} Hz" for f in freqs) + " |",
              "|---|" + "---|" * len(freqs),
              *[f"| {name} | " + " | ".join(f"{g:.3g}" for g in gain) + " |"
                for name, gain in parts["gains"].items()], ""]
    if "starts" in parts:
        lines += ["## The linear start's fits on other data (`model.order=6`)", "",
                  "Gain at Nyquist over the static gain of the ARX start (the order it starts "
                  "at) and of the Steiglitz–McBride fit, the latter's free-run error variance "
                  "and slowest mode over ARX's on the training records. It starts below 0.01 "
                  "of the error with its slowest mode above 0.5 of ARX's, or where ARX's "
                  "Nyquist/static is above 1 and its own is not, below 0.9 of the error with "
                  "its slowest mode at least 0.9 of ARX's (`model=linear`'s start since "
                  "6968906).", "",
                  "| data | output | ARX order | ARX Nyquist/static | SM Nyquist/static | "
                  "SM/ARX free-run error | SM/ARX slowest mode |", "|---|---|---|---|---|---|---|",
                  *[f"| {r['data']} | {r['output']} | {r['arx_order']} | {r['arx_nyquist']:.3g} | "
                    f"{r['sm_nyquist']:.3g} | {r['sm_error']:.3g} | {r['sm_slowest']:.3g} |"
                    for r in parts["starts"]], ""]
    return "\n".join(lines)


def measure(study: Study, scratch: Path, options: argparse.Namespace) -> dict[str, Any]:
    """Every measurement of the page."""
    fs = float(study.tests[0].fs)
    freqs = np.array(FREQUENCIES_HZ)
    limit = study.limit_v
    clipped = [dataclasses.replace(r, u=np.clip(r.u, -limit, limit)) for r in study.tests]
    parts: dict[str, Any] = {
        "excitation": excitation(study), "placement": placement(study),
        "clipped": free_run_rmse(study.start, clipped, study.n_init), "frequencies": freqs,
        "gains": {"simulator": simulator_gain(study, freqs, fs),
                  "round 0": model_gain(study.start, freqs, fs)},
        "refits": {},
    }
    for i, (tag, (weight, level, mode)) in enumerate(VARIANTS.items()):
        model, rmse, loss = refit(study, scratch / f"refit_{i}", weight, level, mode)
        parts["refits"][tag] = (*block_parameters(model), loss, rmse)
        parts["gains"][f"refit: {tag}"] = model_gain(model, freqs, fs)
        log.info("%s: %s", tag, rmse)
    if options.sm_start:
        parts["sm_start"] = sm_start_loop(study, scratch / "sm_start")
    if options.starts:
        parts["starts"] = starts()
    if options.order3:
        parts["order3"] = order3_loop(study, scratch / "order3")
        model = load_model(round_model(scratch / "order3", 1))
        parts["gains"]["`model.order=3`: the loop's refit"] = model_gain(model, freqs, fs)
    return parts


def main(argv: list[str] | None = None, write: Callable[[str], Any] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True,
                        help="the saturation case's loop run (undeclared_effects.py --root)")
    parser.add_argument("--scratch", type=Path, default=Path("/tmp/saturation_refit"))
    parser.add_argument("--order3", action="store_true",
                        help="also run the loop with model.order=3 (about a minute)")
    parser.add_argument("--sm-start", action="store_true",
                        help="also run the loop with the output-error start (about a minute)")
    parser.add_argument("--starts", action="store_true",
                        help="also fit the linear start on other data (about two minutes)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    study = Study.load(args.run.resolve())
    parts = measure(study, args.scratch, args)
    flags = [f" --{flag}" for flag, on in (("order3", args.order3), ("sm-start", args.sm_start),
                                            ("starts", args.starts)) if on]
    command = "python experiments/saturation_refit.py --run <root>/saturation" + "".join(flags)
    text = page(study, parts, command)
    (write or OUT.write_text)(text)
    log.info("wrote %s", OUT)


if __name__ == "__main__":
    main()
