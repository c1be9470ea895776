"""The physical models on a zoo of drawn positioners, through the user-CSV path.

    python benchmarks/zoo.py --plants 30 --seed 0 --jobs 2     # plants 0 ... 29
    python benchmarks/zoo.py --refit greybox --jobs 2          # one model again, same plants
    python benchmarks/zoo.py --plants 17 --seed 13 --fits greybox  # one model on new plants
    python benchmarks/zoo.py --render                          # only rewrite the page

Each plant (`hysteresis_lab.sim.zoo.draw_plant`, seeds ``seed ... seed + plants - 1``) is
exported to CSV (`export_zoo_plant`: the 500-line multisine to train, a second realisation
to validate, the study's twelve ±100 V sines to test) and fitted as a user would, default
settings, three ways: ``hysteresis-lab-train model=greybox data=csv ...``,
``hysteresis-lab-train model=linear model.effects=[hysteresis] data=csv ...`` and
``hysteresis-lab-loop model=linear model.effects=[] data=csv ...`` (the loop's result).
Only the progress bar and TensorBoard are off, which change no number. A plant's results go
to ``<root>/plant_<seed>/result.json`` and are skipped when they exist (resume); every
finished plant is merged into ``docs/results/zoo.json`` and ``docs/results/zoo.md`` is
regenerated from it. ``--refit FIT`` fits one of the three again on every plant kept in
``zoo.json`` (after a change to that model) and keeps the others' results; each fit records
its own commit. ``--fits`` fits only some of the three on new plants (the page counts each
model over the plants it was fitted on). Scores are free-run RMSE over the plant's sensor
noise σ.
"""

from __future__ import annotations

import argparse
import datetime
import json
import logging
import math
import os
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from hysteresis_lab.evaluation.provenance import commit_stamp
from hysteresis_lab.sim.zoo import export_zoo_plant

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "results" / "zoo.md"
KEPT = OUT.with_suffix(".json")
QUIET = ["logger=none", "trainer.enable_progress_bar=false"]
#: the three fits: name -> (console script, overrides)
FITS: dict[str, tuple[str, list[str]]] = {
    "greybox": ("hysteresis-lab-train", ["model=greybox"]),
    "linear+hysteresis": ("hysteresis-lab-train", ["model=linear", "model.effects=[hysteresis]"]),
    "loop": ("hysteresis-lab-loop", ["model=linear", "model.effects=[]"]),
}
#: the issue's targets, in units of the plant's noise σ
MEDIAN_TARGET, P90_TARGET = 1.5, 3.0

log = logging.getLogger("zoo")
#: plants finishing at once write the kept rows and the page one after the other
WRITING = threading.Lock()


def script(name: str) -> str:
    """The console script of this interpreter's environment (else the one on PATH)."""
    beside = Path(sys.executable).parent / name
    found = str(beside) if beside.is_file() else shutil.which(name)
    if not found:
        raise SystemExit(f"{name} not found: install the package (pip install -e .)")
    return found


def data_overrides(files: dict[str, Any]) -> list[str]:
    return ["data=csv", f"data.train={files['train']}", f"data.val={files['val']}",
            f"data.test=[{','.join(files['test'])}]"]


def run_fit(fit: str, files: dict[str, Any], folder: Path) -> dict[str, Any]:
    """One fit of a plant into ``folder`` (fresh); its command, wall time and metrics."""
    program, overrides = FITS[fit]
    command = [script(program), *overrides, *data_overrides(files), *QUIET,
               f"hydra.run.dir={folder}"]
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    start = time.perf_counter()
    with (folder / "zoo_fit.log").open("w") as handle:
        proc = subprocess.run(command, cwd=REPO, env=env, stdout=handle,
                              stderr=subprocess.STDOUT, check=False)
    seconds = time.perf_counter() - start
    shown = " ".join([Path(command[0]).name, *overrides, "data=csv ...", *QUIET])
    if proc.returncode != 0:
        return {"command": shown, "seconds": seconds, "failed": f"exit {proc.returncode}",
                "log": str(folder / "zoo_fit.log")}
    return {"command": shown, "seconds": seconds, **read_scores(fit, folder)}


def read_scores(fit: str, folder: Path) -> dict[str, Any]:
    """Free-run RMSE per test, validation MSE (scaled) and, for the loop, what it added."""
    from hysteresis_lab.run_folder import LoopFolder, RunFolder

    if fit == "loop":  # the report holds the result round's scores (its fit may sit in
        # the folder of the refit rate that won)
        report = json.loads(LoopFolder(folder).report_json.read_text())
        result = report["result"] if report["result"] is not None else 0
        chosen = report["rounds"][result]
        held_out = (chosen.get("held_out") or {}).get("rmse") or {}
        return {"tests": {name: float(m["rmse_free_run"]) for name, m in chosen["tests"].items()},
                "min_r2": min(float(m["r2_free_run"]) for m in chosen["tests"].values()),
                "val_rmse": float(np.mean(list(held_out.values()))) if held_out else None,
                "effects": chosen["effects"],
                "start_rmse": report["rounds"][0]["mean_rmse_free_run"]}
    metrics = RunFolder(folder).read_metrics()
    tests = {name: float(m["rmse_free_run"]) for name, m in metrics["tests"].items()}
    r2 = {name: float(m["r2_free_run"]) for name, m in metrics["tests"].items()}
    return {"tests": tests, "min_r2": min(r2.values()), "val_mse_scaled":
            metrics.get("val_mse_scaled"), "train_seconds": metrics.get("train_seconds")}


def finished_fit(fit: str, folder: Path) -> dict[str, Any] | None:
    """A fit that finished in ``folder`` before the benchmark stopped (its scores, its wall
    time from its config to its last file); None where it did not finish."""
    from hysteresis_lab.run_folder import LoopFolder, RunFolder

    done = LoopFolder(folder).report_json if fit == "loop" else RunFolder(folder).metrics
    start = folder / ".hydra" / "config.yaml"
    if not (done.is_file() and start.is_file()):
        return None
    _, overrides = FITS[fit]
    shown = " ".join([FITS[fit][0], *overrides, "data=csv ...", *QUIET])
    return {"command": shown, "seconds": done.stat().st_mtime - start.stat().st_mtime,
            **read_scores(fit, folder)}


def run_plant(seed: int, root: Path, stamp: dict[str, str],
              fits: tuple[str, ...] = tuple(FITS)) -> dict[str, Any]:
    """Export plant ``seed`` and fit it the ways ``fits`` names (a fit done before is
    reused)."""
    folder = root / f"plant_{seed}"
    result_path = folder / "result.json"
    if result_path.is_file():
        log.info("plant %d: reusing %s", seed, result_path)
        return json.loads(result_path.read_text())
    files = export_zoo_plant(seed, folder / "data")
    plant = json.loads((folder / "data" / "plant.json").read_text())
    y_train = np.loadtxt(files["train"], delimiter=",", skiprows=1)[:, -1]
    sigma = plant["effects"]["noise"]["rms_um"]
    row: dict[str, Any] = {"seed": seed, "description": plant["description"],
                           "noise_um": sigma, "y_scale": float(np.std(y_train)),
                           "gaps": gap_sizes(plant["effects"], sigma), "fits": {}, **stamp}
    for fit in FITS:
        partial = folder / f"{fit}.json"
        if partial.is_file():
            row["fits"][fit] = json.loads(partial.read_text())
            continue
        if fit not in fits:
            continue
        log.info("plant %d: %s", seed, fit)
        fit_folder = folder / fit.replace("+", "_")
        row["fits"][fit] = finished_fit(fit, fit_folder) or run_fit(fit, files, fit_folder)
        partial.write_text(json.dumps(row["fits"][fit], indent=1) + "\n")
        log.info("plant %d: %s %s", seed, fit, summary(row, fit))
    if set(row["fits"]) == set(FITS):  # a plant missing a fit is run again for it
        result_path.write_text(json.dumps(row, indent=1) + "\n")
    return row


# ------------------------------------------------------------------------------ scoring
def score(row: dict[str, Any], fit: str) -> dict[str, Any]:
    """A fit's free-run RMSE over σ: mean over the tests, worst test, validation; diverged
    where a test is not finite or worse than its mean (R² < 0)."""
    if fit not in row["fits"]:
        return {"absent": True, "diverged": False}
    result = row["fits"][fit]
    sigma = row["noise_um"]
    if "tests" not in result:
        return {"failed": result.get("failed", "not run"), "diverged": True}
    tests = result["tests"]
    values = np.array(list(tests.values()))
    worst = max(tests, key=lambda k: tests[k] if math.isfinite(tests[k]) else math.inf)
    val = result.get("val_mse_scaled")
    val_sigma = (math.sqrt(val) * row["y_scale"] / sigma
                 if val is not None and math.isfinite(val) else math.nan)
    if result.get("val_rmse") is not None:  # the loop's held-out RMSE, in the output's units
        val_sigma = result["val_rmse"] / sigma
    diverged = not np.all(np.isfinite(values)) or result["min_r2"] < 0
    return {"ratio": float(np.mean(values)) / sigma, "worst": worst.replace("test_sine_", ""),
            "worst_ratio": tests[worst] / sigma, "val_ratio": val_sigma, "diverged": diverged,
            "seconds": result["seconds"]}


def summary(row: dict[str, Any], fit: str) -> str:
    s = score(row, fit)
    if "ratio" not in s:
        return f"failed ({s['failed']})"
    return f"{s['ratio']:.3g} σ (worst {s['worst']} {s['worst_ratio']:.3g} σ)"


def _without(effects: dict[str, Any], gap: str) -> dict[str, Any] | None:
    """The plant's blocks with one piece a model lacks taken out (None: no such piece)."""
    e = json.loads(json.dumps(effects))
    h = e["hysteresis"]
    if gap == "exponent":
        if h["cell"] != "bouc_wen" or abs(h["exponent"] - 1.0) < 1e-9:
            return None
        # the n = 1 cell with the same alpha and saturated state
        h_sat = (h["alpha"] * h["d_um_per_v"] / (h["beta"] + h["gamma"])) ** (1 / h["exponent"])
        ratio = h["gamma"] / h["beta"]
        h["beta"] = h["alpha"] * h["d_um_per_v"] / h_sat / (1.0 + ratio)
        h["gamma"], h["exponent"] = ratio * h["beta"], 1.0
    elif gap in ("asymmetry", "creep"):
        if not e[gap]["enabled"]:
            return None
        e[gap]["enabled"] = False
    elif gap == "modes":
        if not (e["mode2"]["enabled"] or e["mode3"]["enabled"]):
            return None
        e["mode2"]["enabled"] = e["mode3"]["enabled"] = False
    elif gap == "delay":
        if e["input_delay"]["samples"] == 1:
            return None
        e["input_delay"]["samples"] = 1
    return e


#: the pieces of a zoo plant a model may lack, each one's size measured (`gap_sizes`)
PIECES = ("exponent", "asymmetry", "creep", "modes", "delay")
#: pieces outside each model's class with its defaults: the greybox reads its delay and 1-3
#: modes (a feedthrough beside them) off the data and carries an asymmetric term, its cell a
#: Bouc-Wen one whose exponent the L-BFGS polish learns or a Prandtl-Ishlinskii one;
#: model=linear's cell is Bouc-Wen of exponent 1 or Prandtl-Ishlinskii, without an asymmetric
#: term; neither carries creep undeclared. The loop can grow asymmetry and creep (`GROWN`)
GAPS = {"greybox": ("creep",),
        "linear+hysteresis": ("exponent", "asymmetry", "creep"),
        "loop": ("exponent",)}
#: pieces the loop can add, each with the effect that adds it: a loop fit that did not keep
#: it misses it by its diagnosis, not its structure
GROWN = {"asymmetry": "asymmetry", "creep": "creep"}
#: the models whose cell can be a Prandtl-Ishlinskii one (model.hysteresis=auto; the loop
#: tries both cells when it adds hysteresis: every kept loop fit is newer than 758eaf4)
HOLD_PLAYS = ("greybox", "linear+hysteresis", "loop")


def gap_sizes(effects: dict[str, Any], sigma: float) -> dict[str, float]:
    """Each missing piece's size: the noise-free RMSE over the twelve test sines between the
    plant and the plant without it, over σ (what a model without it cannot follow, unless
    its other parts absorb some)."""
    from hysteresis_lab.sim.default_dataset import TEST_FREQUENCIES_HZ, sine_signal
    from hysteresis_lab.sim.positioner import Positioner

    quiet = {"noise": {"enabled": False}, "quantisation": {"enabled": False}}
    inputs = [sine_signal(f, 20_000.0, 100.0) for f in TEST_FREQUENCIES_HZ]
    plant = Positioner({**effects, **quiet})
    sizes = {}
    for gap in PIECES:
        other = _without(effects, gap)
        if other is None:
            continue
        changed = Positioner({**other, **quiet})
        rmse = [np.sqrt(np.mean((plant.simulate(u, 20_000.0) - changed.simulate(u, 20_000.0))
                                ** 2)) for u in inputs]
        sizes[gap] = float(np.mean(rmse)) / sigma
    return sizes


def _sized_pieces(row: dict[str, Any], pieces: Sequence[str]) -> list[str]:
    """Each of ``pieces`` of the plant named with its size (`gap_sizes`), those smaller than
    σ left out (a piece below the noise is no miss's reason)."""
    d, sizes = row["description"], row.get("gaps", {})
    names = {"exponent": f"Bouc–Wen n = {d.get('exponent', 1.0):.2f}",
             "asymmetry": "asymmetric loop",
             "creep": f"creep {100 * d['creep_per_decade']:.1f} %/decade",
             "modes": f"{len(d['modes_hz'])} modes",
             "delay": f"{d['delay_samples']} samples of delay"}
    return [f"{names[piece]} ({sizes[piece]:.3g} σ)" for piece in pieces
            if sizes.get(piece, 0.0) >= 1.0]


def structure_gaps(row: dict[str, Any], fit: str) -> list[str]:
    """What of the plant lies outside the fitted model's class, each with its size (pieces
    smaller than σ left out)."""
    d = row["description"]
    gaps = []
    if d["cell"] == "prandtl_ishlinskii" and fit not in HOLD_PLAYS:
        gaps.append(f"Prandtl–Ishlinskii cell ({d['plays']} plays, share {d['pi_share']:.2f})")
    return gaps + _sized_pieces(row, GAPS[fit])


def not_grown(row: dict[str, Any]) -> list[str]:
    """The pieces of the plant the loop could have added but did not keep, each with its
    size (pieces smaller than σ left out)."""
    kept = row["fits"].get("loop", {}).get("effects", [])
    return _sized_pieces(row, [piece for piece, effect in GROWN.items() if effect not in kept])


def why(row: dict[str, Any], fit: str) -> str:
    """Why a fit misses 3 σ, with numbers: excitation (validation far better than the tests),
    start (the loop's grown path far better), structure (what the model cannot hold),
    optimiser (validation itself far above σ with nothing structural missing)."""
    s = score(row, fit)
    if "ratio" not in s:
        return f"the fit failed ({s['failed']})"
    reasons = []
    if s["diverged"]:
        reasons.append("diverged (a test's R² < 0)")
    val = s["val_ratio"]
    if math.isfinite(val) and s["ratio"] > 2.0 * val:
        reasons.append(f"excitation: validation multisine {val:.3g} σ, tests {s['ratio']:.3g} σ "
                       f"(worst {s['worst']} {s['worst_ratio']:.3g} σ)")
    loop = score(row, "loop")
    if fit != "loop" and "ratio" in loop and loop["ratio"] < s["ratio"] / 1.2:
        reasons.append(f"start: the grown loop reaches {loop['ratio']:.3g} σ")
    gaps = structure_gaps(row, fit)
    missed = not_grown(row) if fit == "loop" else []
    if gaps:
        reasons.append("structure (each piece's size alone): " + ", ".join(gaps))
    if missed:
        reasons.append("diagnosis: not added, though the loop can: " + ", ".join(missed))
    if not gaps and not missed and math.isfinite(val) and val > 3.0:
        reasons.append(f"optimiser: validation {val:.3g} σ with the plant inside the class")
    if not any(reason.startswith("excitation") for reason in reasons):
        reasons.append(f"validation {val:.3g} σ, tests {s['ratio']:.3g} σ")
    return "; ".join(reasons)


# ------------------------------------------------------------------------------ the page
def load_kept(path: Path = KEPT) -> dict[str, dict]:
    return json.loads(path.read_text()) if path.is_file() else {}


def keep(rows: list[dict[str, Any]], path: Path = KEPT) -> dict[str, dict]:
    kept = {**load_kept(path), **{str(r["seed"]): r for r in rows}}
    kept = dict(sorted(kept.items(), key=lambda item: int(item[0])))
    path.write_text(json.dumps(kept, indent=1) + "\n")
    return kept


def plant_cell(row: dict[str, Any]) -> str:
    d = row["description"]
    cell = (f"PI {d['plays']}" if d["cell"] == "prandtl_ishlinskii"
            else f"BW n {d['exponent']:.2f}, γ/β {d['rate_ratio']:+.2f}")
    modes = "/".join(f"{f:.0f}" for f in d["modes_hz"])
    extras = [x for x, on in (("asym", d["asymmetry"]), ("creep", d["creep_per_decade"] > 0))
              if on]
    return (f"{cell}; d {d['d_um_per_v']:.2f}; modes {modes} Hz; amp {d['amplifier_hz'] / 1e3:.1f}"
            f" kHz; delay {d['delay_samples']}" + (f"; {', '.join(extras)}" if extras else ""))


def fit_cell(row: dict[str, Any], fit: str) -> str:
    s = score(row, fit)
    if s.get("absent"):
        return "not fitted"
    if "ratio" not in s:
        return f"failed ({s['failed']})"
    mark = " **diverged**" if s["diverged"] else ""
    return f"{s['ratio']:.3g} ({s['worst']} {s['worst_ratio']:.3g}){mark}"


def fit_commits(row: dict[str, Any], fit: str) -> str:
    """The commit a plant's fit ran at (a refit's own, else its plant row's)."""
    return (row["fits"].get(fit) or {}).get("commit", row["commit"])


def statistics(kept: dict[str, dict], fit: str) -> str:
    """The model's row of the summary, over the plants it was fitted on."""
    kept = {seed: row for seed, row in kept.items() if fit in row["fits"]}
    scores = [score(row, fit) for row in kept.values()]
    commits = sorted({fit_commits(row, fit) for row in kept.values()})
    ratios = np.array([s.get("ratio", math.inf) for s in scores])
    diverged = sum(s["diverged"] for s in scores)
    median, p90 = np.median(ratios), np.percentile(ratios, 90)
    met = median <= MEDIAN_TARGET and p90 <= P90_TARGET and diverged == 0
    seconds = [s["seconds"] for s in scores if "seconds" in s]
    outside = sum(bool(structure_gaps(row, fit)) for row in kept.values())
    return (f"| {fit} ({len(kept)} plants) | {median:.3g} σ | {p90:.3g} σ | {diverged} | "
            f"{'met' if met else 'missed'} | {outside} of {len(kept)} | "
            f"{np.median(seconds):.0f} s | {', '.join(commits)} |")


def fewer_fits(rows: list[dict[str, Any]]) -> str:
    """The models fitted on fewer plants than the page shows (``--fits``), with their count."""
    counts = {fit: sum(fit in r["fits"] for r in rows) for fit in FITS}
    fewer = [f"`{fit}` on {n}" for fit, n in counts.items() if n < len(rows)]
    return f" Fitted on fewer plants: {', '.join(fewer)}." if fewer else ""


def render(kept: dict[str, dict]) -> str:
    rows = list(kept.values())
    commits = sorted({fit_commits(r, fit) for r in rows for fit in FITS if fit in r["fits"]})
    dates = sorted({(r["fits"].get(fit) or {}).get("date", r["date"]) for r in rows
                    for fit in FITS if fit in r["fits"]})
    lines = [
        "# The physical models on a zoo of positioners",
        "",
        f"Command: `python benchmarks/zoo.py --plants N --seed S --jobs J` (resumes; "
        "`--refit <model>` fits one model again on the kept plants; "
        f"`--render` rewrites this page from `zoo.json`); commit {', '.join(commits)}; "
        f"{', '.join(dates)}; shared 2-core CPU (OMP_NUM_THREADS=1, other work running: "
        "times are rough).",
        "",
        f"**{len(rows)} plants** (seeds {', '.join(kept)}) drawn from the zoo's prior "
        "([docs/zoo.md](../zoo.md)), each exported to CSV and fitted through `data=csv` with "
        "default settings: trained on the 500-line multisine, validated on a second "
        "realisation, tested on the study's twelve ±100 V sines. The issue asks for at least "
        "30 plants; " + ("this run has them." if len(rows) >= 30 else "this run has fewer "
                         "(the machine was shared; rerun with more plants to extend it).")
        + fewer_fits(rows),
        "",
        "Scores are the mean free-run RMSE (from rest, `evaluation.initial_state=rest`) over "
        "the twelve tests divided by the plant's "
        f"sensor noise σ. Target for each model: median ≤ {MEDIAN_TARGET} σ, 90th "
        f"percentile ≤ {P90_TARGET} σ, no plant diverging (a test not finite or with "
        "R² < 0).",
        "",
        "| model | median | 90th percentile | diverged | target | plants outside the model's "
        "class | median fit time | commit |",
        "|---|---|---|---|---|---|---|---|",
        *(statistics(kept, fit) for fit in FITS),
        "",
        "Per plant: mean RMSE / σ (worst sine in Hz and its RMSE / σ). `loop` is "
        "`hysteresis-lab-loop model=linear model.effects=[]`'s result, with the effects it "
        "kept.",
        "",
        "| seed | plant | σ (µm) | greybox | linear + hysteresis | loop | loop kept |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        loop = row["fits"].get("loop", {})
        lines.append(f"| {row['seed']} | {plant_cell(row)} | {row['noise_um']:.3g} | "
                     f"{fit_cell(row, 'greybox')} | {fit_cell(row, 'linear+hysteresis')} | "
                     f"{fit_cell(row, 'loop')} | {', '.join(loop.get('effects', [])) or '-'} |")
    lines += ["", "## Why a plant misses (> 3 σ)", "",
              "Excitation: the validation multisine is fitted far better than the tests; "
              "start: the loop's grown path does better from the same data; structure: what "
              "the plant has that the model cannot hold with its defaults (the greybox: the "
              "delay and 1–3 modes with a feedthrough read off the data, an asymmetric term, "
              "a Bouc–Wen cell whose exponent the L-BFGS polish learns or a "
              "Prandtl–Ishlinskii cell, no creep undeclared; `model=linear`: a Bouc–Wen cell "
              "of exponent 1 or a Prandtl–Ishlinskii cell, no asymmetric term, no creep "
              "undeclared; the loop: a Bouc–Wen cell of exponent 1 or a Prandtl–Ishlinskii "
              "cell, and the effects it adds); diagnosis: an asymmetry or creep the loop "
              "could have added and did not; optimiser: validation far above σ with nothing "
              "structural missing. Validation RMSE is read from the fit's scaled validation "
              "loss times the training output's standard deviation (the CSV path's standard "
              "scaling); the loop's is its held-out RMSE.", ""]
    for row in rows:
        for fit in FITS:
            s = score(row, fit)
            if s.get("absent"):
                continue
            if "ratio" not in s or s["ratio"] > P90_TARGET or s["diverged"]:
                lines.append(f"- plant {row['seed']}, {fit}: {why(row, fit)}")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", type=int, default=30)
    parser.add_argument("--seed", type=int, default=0, help="the first plant's seed")
    parser.add_argument("--jobs", type=int, default=1, help="plants fitted at once")
    parser.add_argument("--root", type=Path, default=REPO / "outputs" / "zoo")
    parser.add_argument("--render", action="store_true", help="only rewrite the page")
    parser.add_argument("--refit", choices=sorted(FITS),
                        help="fit this model again on the plants kept in zoo.json whose seeds "
                             "--seed and --plants name (by default every kept plant)")
    parser.add_argument("--fits", default=",".join(FITS),
                        help=f"which of {', '.join(FITS)} to fit on new plants")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    if args.refit and not args.render:
        refit_kept(args.refit, args.root, args.jobs,
                   range(args.seed, args.seed + args.plants))
    elif not args.render:
        stamp = {"commit": commit_stamp(REPO, ["src", "benchmarks"]),
                 "date": datetime.date.today().isoformat()}
        seeds = range(args.seed, args.seed + args.plants)

        fits = tuple(args.fits.split(","))
        unknown = sorted(set(fits) - set(FITS))
        if unknown:
            raise SystemExit(f"--fits {args.fits}: no fit {unknown}; choose from "
                             f"{', '.join(FITS)}")

        def one(seed: int) -> dict[str, Any]:
            row = run_plant(seed, args.root, stamp, fits)
            with WRITING:  # a finished plant is kept at once (the page survives a stop)
                OUT.write_text(render(keep([row])))
            return row

        with ThreadPoolExecutor(max_workers=args.jobs) as pool:
            list(pool.map(one, seeds))
    OUT.write_text(render(backfill_gaps(load_kept(), args.root)))
    log.info("wrote %s", OUT)


def refit_kept(fit: str, root: Path, jobs: int, seeds: Sequence[int]) -> None:
    """``fit`` again on the plants kept in ``zoo.json`` whose seed is in ``seeds``, its result
    (with its commit and date) replacing the kept one; each plant is kept as soon as it is
    done."""
    stamp = {"commit": commit_stamp(REPO, ["src", "benchmarks"]),
             "date": datetime.date.today().isoformat()}

    def one(row: dict[str, Any]) -> None:
        seed = row["seed"]
        folder = root / f"plant_{seed}"
        files = export_zoo_plant(seed, folder / "data")
        drawn = json.loads((folder / "data" / "plant.json").read_text())["description"]
        if drawn != row["description"]:
            raise SystemExit(f"plant {seed} is no longer the kept one (the zoo's prior "
                             "changed): rerun the whole zoo instead of --refit")
        log.info("plant %d: %s again", seed, fit)
        result = run_fit(fit, files, folder / fit.replace("+", "_"))
        fresh = {**row, "fits": {**row["fits"], fit: {**result, **stamp}}}
        with WRITING:
            OUT.write_text(render(keep([fresh])))
        log.info("plant %d: %s %s", seed, fit, summary(fresh, fit))

    with ThreadPoolExecutor(max_workers=jobs) as pool:
        list(pool.map(one, [row for row in load_kept().values() if row["seed"] in seeds]))


def backfill_gaps(kept: dict[str, dict], root: Path) -> dict[str, dict]:
    """Rows kept before their pieces' sizes were measured get them from their plant file."""
    missing = [row for row in kept.values() if "gaps" not in row]
    for row in missing:
        plant = json.loads((root / f"plant_{row['seed']}" / "data" / "plant.json").read_text())
        row["gaps"] = gap_sizes(plant["effects"], row["noise_um"])
    return keep(missing) if missing else kept


if __name__ == "__main__":
    main()
