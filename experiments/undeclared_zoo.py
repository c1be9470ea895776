"""Undeclared effects on hysteretic zoo plants: does the loop name and fix them (issue #36
point 4)?

    python experiments/undeclared_zoo.py --plants 5                  # 5 plants per effect
    python experiments/undeclared_zoo.py --plants 1 --effects creep drift --jobs 1
    python experiments/undeclared_zoo.py --render                    # the page from kept rows

`experiments/undeclared_effects.py` switches the simulator's hysteresis off; real positioners
carry theirs. Here each plant is a zoo plant (`hysteresis_lab.sim.zoo.draw_effects`) that
keeps its drawn hysteresis cell, first mode, amplifier, delay, noise and quantisation, and
the start declares the hysteresis (``model=linear model.effects=[hysteresis]``). The zoo's
other blocks that are effects of their own (creep, the asymmetric loop, a second and third
mode) are switched off in the *base* plant, and each cell switches exactly one effect on
(`EFFECTS`): creep, a second mode, the asymmetric loop at the plant's drawn parameters where
the plant drew them (else the simulator's defaults); drift, input saturation, backlash, a
dead zone and rate dependence at the simulator's defaults, as in `undeclared_effects.py`.
Rate dependence scales the Bouc–Wen cell's ``alpha`` and is not in the simulator for a
Prandtl–Ishlinskii cell: such plants are skipped for it (and said so) and the next seed taken.

Each cell runs ``hysteresis-lab-loop`` with ``loop.max_rounds=1`` and is judged with the
bundled experiment's own code (`undeclared_effects.case_row`: the rule, the ceiling). Per
plant a *base* run (``loop.max_rounds=0``, the effect not added) measures how far the
declared start already is from the plant: its free-run RMSE over the plant's noise σ, and on
each test where the added effect acts, that error over the effect's own size (> 1: the
start's own misfit is larger than the effect it should reveal).

Resumable: each cell's row is kept under ``--root/<seed>/<effect>/row.json``, merged into
``docs/results/undeclared_zoo.json``; the page ``docs/results/undeclared_zoo.md`` shows every
kept cell.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import datetime
import functools
import importlib.util
import json
import logging
import math
import multiprocessing
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from undeclared_effects import (  # the script beside (Python puts its folder on the path)
    CASE_DATA,
    CASES,
    QUIET,
    _others_cell,
    _tests_cell,
    _verdict_cell,
    case_row,
)

from hysteresis_lab.cli.loop import run_fresh_loop
from hysteresis_lab.effects.registry import available_effects
from hysteresis_lab.evaluation.provenance import commit_stamp
from hysteresis_lab.sim.config import PositionerConfig
from hysteresis_lab.sim.zoo import describe, draw_effects

log = logging.getLogger("undeclared_zoo")

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "results" / "undeclared_zoo.md"
#: the zoo's blocks that are effects the cells add: off in the base plant
ADDED_IN_TURN = ("creep", "asymmetry", "mode2", "mode3")
#: the simulator's asymmetric loop, where the plant drew none (+0.02 * 40 µm at ±100 V)
ASYMMETRY_DEFAULT = {"coefficient": 0.02, "v_ref": 100.0}
#: mode2 where the plant drew one mode: the simulator's default second mode
MODE2_DEFAULT = {"frequency_hz": 2800.0, "damping": 0.02, "weight": 0.15}
#: ``--quick``: a cell at about half the default loop's fits on a shared CPU: the declared
#: start grown only (not also trained at once), one refit learning rate (training.lr's
#: default) instead of two. (Two folds instead of three would make each fold one whole
#: recording, the short validation multisine alone: starts then diverge on it.)
QUICK = ("model.grow=true", "training.refit_lr=0.002")


def asymmetry_names() -> tuple[str, ...]:
    """The catalogue effects that name an asymmetric loop: ``asymmetry`` where the catalogue
    has it, else the static laws that can hold an even part (stand-ins)."""
    if "asymmetry" in available_effects():
        return ("asymmetry",)
    return ("nonlinear_feedback", "saturation", "overflow")


def effect_names(effect: str) -> tuple[str, ...]:
    """The catalogue effects that name simulator block ``effect`` (the bundled cases')."""
    if effect == "asymmetry":
        return asymmetry_names()
    return CASES[effect][2]


#: the effects added in turn, each a simulator block
EFFECTS = ("creep", "mode2", "drift", "saturation", "backlash", "dead_zone",
           "rate_dependence", "asymmetry")


def base_effects(seed: int) -> dict[str, Any]:
    """Zoo plant ``seed`` with its hysteresis, first mode and linear parts; the blocks the
    cells add in turn switched off."""
    effects = draw_effects(seed)
    for block in ADDED_IN_TURN:
        effects[block] = {**effects[block], "enabled": False}
    return effects


def added_block(seed: int, effect: str) -> dict[str, Any] | None:
    """The parameters of ``effect`` added to plant ``seed`` (None: the simulator has no such
    effect on this plant's cell)."""
    drawn = draw_effects(seed)
    if effect == "rate_dependence" and drawn["hysteresis"]["cell"] != "bouc_wen":
        return None
    if effect == "creep":
        return {"enabled": True, "weight_per_decade": drawn["creep"]["weight_per_decade"]}
    if effect == "asymmetry":
        own = drawn["asymmetry"]
        return {**(own if own["enabled"] else ASYMMETRY_DEFAULT), "enabled": True}
    if effect == "mode2":
        own = drawn["mode2"]
        return {**(own if own["enabled"] else MODE2_DEFAULT), "enabled": True}
    return {"enabled": True}


def _value(value: Any) -> str:
    """A Hydra override's value."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list | tuple):
        return "[" + ",".join(_value(v) for v in value) + "]"
    return repr(value) if isinstance(value, float) else str(value)


def effect_overrides(effects: dict[str, Any]) -> list[str]:
    """``data.effects.<block>.<key>=<value>`` for every key of every block."""
    return [f"data.effects.{block}.{key}={_value(value)}"
            for block, params in effects.items() for key, value in params.items()]


def plant_overrides(seed: int, effect: str | None) -> list[str]:
    """The base plant ``seed`` with ``effect`` switched on (None: the base plant)."""
    effects = base_effects(seed)
    if effect is not None:
        block = added_block(seed, effect)
        if block is None:
            raise ValueError(f"plant {seed} has no {effect}: {why_skipped(seed, effect)}")
        effects[effect] = {**effects[effect], **block}
    return effect_overrides(effects)


def why_skipped(seed: int, effect: str) -> str:
    return (f"the simulator's {effect} scales the Bouc–Wen alpha; plant {seed} has a "
            f"{draw_effects(seed)['hysteresis']['cell']} cell")


def command(seed: int, effect: str | None, rounds: int = 1,
            extra: tuple[str, ...] = ()) -> list[str]:
    """The loop command of a cell (``effect`` None: the plant's base run, round 0 only;
    ``extra``: overrides added, e.g. smaller data for a quick check)."""
    data = CASE_DATA.get(effect, []) if effect else []
    return ["hysteresis-lab-loop", "model.effects=[hysteresis]",
            *plant_overrides(seed, effect), *data,
            f"loop.max_rounds={rounds if effect else 0}", *QUIET, *extra]


def shown_command(seed: int, effect: str | None, rounds: int = 1,
                  extra: tuple[str, ...] = ()) -> str:
    """The command as the page shows it: the plant's ~50 overrides named, not listed."""
    data = CASE_DATA.get(effect, []) if effect else []
    added = (" " + " ".join(f"data.effects.{effect}.{k}={_value(v)}"
                            for k, v in added_block(seed, effect).items())) if effect else ""
    return (f"hysteresis-lab-loop model.effects=[hysteresis] <base plant {seed}>{added}"
            + "".join(f" {d}" for d in data)
            + f" loop.max_rounds={rounds if effect else 0} {' '.join([*QUIET, *extra])}")


def plants_for(effect: str, count: int, first: int) -> list[int]:
    """The first ``count`` seeds from ``first`` on whose cell the simulator's ``effect``
    acts on."""
    seeds, seed = [], first
    while len(seeds) < count:
        if added_block(seed, effect) is not None:
            seeds.append(seed)
        seed += 1
    return seeds


@functools.cache
def exponent_gap(seed: int) -> float | None:
    """How much of base plant ``seed`` the declared model's Bouc–Wen cell of exponent 1
    cannot hold: the noise-free RMSE over the twelve test sines between the plant and its
    ``n = 1`` cell of the same ``alpha`` and saturated state, over σ (``benchmarks/zoo.py``'s
    `gap_sizes`); None for a Prandtl–Ishlinskii cell, outside the model's class altogether."""
    effects = base_effects(seed)
    if effects["hysteresis"]["cell"] != "bouc_wen":
        return None
    spec = importlib.util.spec_from_file_location("zoo_benchmark", REPO / "benchmarks" / "zoo.py")
    benchmark = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(benchmark)
    return benchmark.gap_sizes(effects, effects["noise"]["rms_um"]).get("exponent", 0.0)


# ----------------------------------------------------------------------------- runs
def run_base(seed: int, root: Path, extra: tuple[str, ...] = ()) -> dict[str, Any]:
    """The declared start on the base plant: free-run RMSE per test, over σ."""
    path = root / str(seed) / "base" / "row.json"
    if _kept(path, extra):
        return json.loads(path.read_text())
    report, seconds = run_fresh_loop(command(seed, None, extra=extra)[1:], path.parent)
    tests = {t: m["rmse_free_run"] for t, m in report["rounds"][0]["tests"].items()}
    sigma = draw_effects(seed)["noise"]["rms_um"]
    row = {"seed": seed, "sigma_um": sigma, "tests": tests, "extra": list(extra),
           "mean_over_sigma": float(np.mean(list(tests.values()))) / sigma,
           "seconds": seconds, "command": shown_command(seed, None, extra=extra),
           "commit": commit_stamp(REPO, ("src", "experiments")),
           "date": f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M}"}
    path.write_text(json.dumps(row, indent=1))
    return row


def _kept(path: Path, extra: tuple[str, ...]) -> bool:
    """Is a row kept at ``path`` from a run with the same added overrides?"""
    return path.is_file() and json.loads(path.read_text()).get("extra", []) == list(extra)


def masking(row: dict[str, Any], base: dict[str, Any]) -> dict[str, float]:
    """Per test where the effect acts: the declared start's own error there before the
    effect is added (the base run) over the effect's size (> 1: the misfit hides it)."""
    return {t: base["tests"][t] / size for t, size in row["effect_size_um"].items()
            if t in base["tests"]}


def diverged(row: dict[str, Any]) -> list[str]:
    """Tests whose free-run error is not finite, before or after the refit."""
    return sorted({t for key in ("before", "after") for t, v in row.get(key, {}).items()
                   if not math.isfinite(v)})


def _claim(lock: Path) -> bool:
    """Take ``lock`` for this process (False: a live process holds it)."""
    lock.parent.mkdir(parents=True, exist_ok=True)
    try:
        with lock.open("x") as handle:
            handle.write(str(os.getpid()))
        return True
    except FileExistsError:
        try:
            os.kill(int(lock.read_text()), 0)
            return False
        except (ProcessLookupError, ValueError):  # a stopped run's lock
            lock.write_text(str(os.getpid()))
            return True


def judged(row: dict[str, Any], base: dict[str, Any]) -> dict[str, Any]:
    """A cell's row with what the zoo adds to the rule: the start's misfit over the effect
    (`masking`), the tests that diverged, and no pass where the loop diagnosed nothing (its
    start diverged on a fold): the rule has nothing to judge there."""
    row = {**row, "masking": masking(row, base), "diverged": diverged(row)}
    if row["top"] is None:
        row["verdict"] = f"no diagnosis: {row.get('why_not_refitted', 'none')}"
    return row


def run_cell(seed: int, effect: str, root: Path, rounds: int = 1,
             extra: tuple[str, ...] = ()) -> dict[str, Any]:
    """One plant × effect cell (kept: read back), judged by the bundled rule (``extra``:
    overrides added to its and its base's command)."""
    path = root / str(seed) / effect / "row.json"
    if _kept(path, extra):
        return json.loads(path.read_text())
    base = run_base(seed, root, extra)
    lock = root / str(seed) / f"{effect}.running"
    if not _claim(lock):  # another invocation runs this cell: its folder is not ours to empty
        log.info("plant %d + %s runs in process %s: left to it", seed, effect,
                 lock.read_text())
        return {}
    log.info("plant %d + %s ...", seed, effect)
    try:
        row = case_row(command(seed, effect, rounds, extra), path.parent, effect,
                       effect_names(effect))
    except RuntimeError as exc:  # a data or config error: the cell says so
        path.parent.mkdir(parents=True, exist_ok=True)
        row = {"failed": str(exc).splitlines()[-1][:300]}
    finally:
        lock.unlink(missing_ok=True)
    row = {"seed": seed, "effect": effect, **row, "extra": list(extra),
           "loop_command": " ".join(command(seed, effect, rounds, extra)),
           "command": shown_command(seed, effect, rounds, extra),
           "base_over_sigma": base["mean_over_sigma"], "sigma_um": base["sigma_um"],
           "exponent_gap_over_sigma": exponent_gap(seed),
           "plant": describe(PositionerConfig.from_dict(base_effects(seed)))}
    if "failed" not in row:
        row = judged(row, base)
    path.write_text(json.dumps(row, indent=1))
    log.info("plant %d + %s: %s", seed, effect, row.get("verdict", row.get("failed")))
    return row


def _run_cell_args(args: tuple[int, str, Path, int, tuple[str, ...]]) -> dict[str, Any]:
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    return run_cell(*args)


def run_cells(cells: list[tuple[int, str]], root: Path, rounds: int, jobs: int,
              extra: tuple[str, ...] = ()) -> None:
    """Run the cells not kept yet (with the same ``extra`` overrides), ``jobs`` at a time
    (each in its own process: the loop holds global logging and torch state)."""
    order = {e: i for i, e in enumerate(EFFECTS)}
    todo = sorted(((s, e) for s, e in cells if not _kept(root / str(s) / e / "row.json", extra)),
                  key=lambda cell: (cell[0], order[cell[1]]))  # plant by plant
    log.info("%d cells to run (%d kept)", len(todo), len(cells) - len(todo))
    if jobs <= 1:
        for seed, effect in todo:
            run_cell(seed, effect, root, rounds, extra)
        return
    # the base runs first, one per plant, so that no two cells fit the same base at once
    plants = sorted({s for s, _ in todo})
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=context) as pool:
        list(pool.map(run_base, plants, [root] * len(plants), [extra] * len(plants)))
        list(pool.map(_run_cell_args, [(s, e, root, rounds, extra) for s, e in todo]))


# ----------------------------------------------------------------------------- the page
def kept_rows(root: Path, kept_path: Path | None = None) -> dict[str, dict]:
    """The rows under ``root`` over those kept in ``kept_path`` (the page's JSON), by
    ``<seed>/<effect>``."""
    kept_path = kept_path or OUT.with_suffix(".json")
    kept = json.loads(kept_path.read_text()) if kept_path.is_file() else {}
    for path in sorted(root.glob("*/*/row.json")):
        if path.parent.name != "base":
            row = json.loads(path.read_text())
            kept[f"{row['seed']}/{row['effect']}"] = row
    for row in kept.values():  # rows kept before the structural gap was measured
        if "exponent_gap_over_sigma" not in row:
            row["exponent_gap_over_sigma"] = exponent_gap(row["seed"])
    order = {e: i for i, e in enumerate(EFFECTS)}
    return dict(sorted(kept.items(), key=lambda kv: (order.get(kv[1]["effect"], 99),
                                                      kv[1]["seed"])))


def passed(row: dict[str, Any]) -> bool:
    return row.get("verdict", "").startswith("PASS")


def plant_cell(row: dict[str, Any]) -> str:
    """The base plant in a few words."""
    d = row["plant"]
    cell = (f"PI {d['plays']}" if d["cell"] == "prandtl_ishlinskii"
            else f"BW n {d['exponent']:.2f}, γ/β {d['rate_ratio']:+.2f}")
    return (f"{cell}; d {d['d_um_per_v']:.2f}; mode {d['modes_hz'][0]:.0f} Hz; "
            f"amp {d['amplifier_hz'] / 1000:.1f} kHz; delay {d['delay_samples']}")


def masking_cell(row: dict[str, Any]) -> str:
    """The declared start's misfit before the effect: mean over σ; on the acting tests its
    error over the effect's size (median, worst)."""
    text = f"{row['base_over_sigma']:.3g} σ"
    gap = row.get("exponent_gap_over_sigma")
    text += (" (PI cell)" if row["plant"]["cell"] == "prandtl_ishlinskii"
             else f" (n ≠ 1 alone {gap:.3g} σ)" if gap is not None else "")
    m = row.get("masking") or {}
    if m:
        values = sorted(m.values())
        text += f"; ×{float(np.median(values)):.2g} the effect (max ×{values[-1]:.2g})"
    return text


def found(row: dict[str, Any]) -> bool:
    """Did the loop name the effect (and, where it predicts it, fix it by the rule)? A pass
    the rule grants because the effect holds too little of the residual is not."""
    return row.get("verdict", "") in ("PASS", "PASS: named, reported, not added")


def hidden(row: dict[str, Any]) -> float | None:
    """The median, over the tests where the effect acts, of the start's misfit over the
    effect's size (None: it acts on no test)."""
    m = row.get("masking") or {}
    return float(np.median(list(m.values()))) if m else None


def why_cell(row: dict[str, Any]) -> str:
    """Why a cell fails, with its numbers (the verdict's, the misfit's); for a pass the rule
    grants unnamed, whether the start's misfit hides the effect."""
    if passed(row):
        ratio = hidden(row)
        if found(row) or ratio is None or ratio <= 1.0:
            return ""
        return (f"a pass by the rule only: not named, the start's misfit is {ratio:.2g}× the "
                "effect where it acts")
    reasons = []
    m = row.get("masking") or {}
    if m and float(np.median(list(m.values()))) > 1.0:
        gap = row.get("exponent_gap_over_sigma")
        cause = (" (a Prandtl–Ishlinskii cell)" if row["plant"]["cell"] == "prandtl_ishlinskii"
                 else f" (its exponent {row['plant']['exponent']:.2f} alone {gap:.3g} σ)"
                 if gap is not None else "")
        reasons.append(f"the declared start misfits the plant by {row['base_over_sigma']:.3g} σ"
                       f"{cause} before the effect is added, "
                       f"{float(np.median(list(m.values()))):.2g}× the effect's own size "
                       "where it acts: the residual hides it")
    share = row.get("effect_share_max")
    if share is not None and share < 0.05:
        reasons.append(f"the effect holds {100 * share:.1f} % of the round-0 residual")
    if row.get("verdict", "").startswith("n/a") and not row.get("recommends"):
        top = max(row["ceiling_pct"].values(), default=0.0)
        reasons.append(f"no excitation advice, though taking the effect off would cut a "
                       f"test's error by up to {top:.0f} %")
    if row.get("diverged"):
        reasons.append(f"diverged on {row['diverged']}")
    if row.get("top") and row["top"] not in row.get("expected", []):
        named = "named" if row.get("significant") else "top, not significant:"
        reasons.append(f"{named} {row['top']} ({100 * (row.get('top_score') or 0):.1f} %)")
    if row.get("effect") == "asymmetry" and "asymmetry" not in row.get("expected", []):
        reasons.append(f"the catalogue has no asymmetry effect (stand-ins "
                       f"{'/'.join(row['expected'])})")
    return "; ".join(reasons)


def statistics(rows: Iterable[dict[str, Any]]) -> tuple[int, int]:
    """(cells that pass, cells judged)."""
    judged = [r for r in rows if "verdict" in r]
    return sum(passed(r) for r in judged), len(judged)


def render(rows: dict[str, dict], skipped: list[str]) -> str:
    """The markdown page of every kept cell."""
    values = list(rows.values())
    good, total = statistics(values)
    commits = sorted({r["commit"] for r in values if "commit" in r})
    dates = sorted({r["date"][:10] for r in values if "date" in r})
    share = f"{100 * good / total:.0f} %" if total else "–"
    lines = [
        "# Undeclared effects on hysteretic zoo plants: does the loop name and fix them?",
        "",
        "Written by `python experiments/undeclared_zoo.py --plants N [--effects ...] "
        "[--jobs J]` (resumes per cell; `--render` rewrites this page from "
        "`undeclared_zoo.json`); commit " + (", ".join(commits) or "–") + "; "
        + (", ".join(dates) or "–") + "; a shared 2-core CPU (OMP_NUM_THREADS=1).",
        "",
        "Each plant is a zoo plant (`hysteresis_lab.sim.zoo.draw_effects(seed)`, "
        "[docs/zoo.md](../zoo.md)) keeping its drawn hysteresis cell, first mode, amplifier, "
        "delay, noise and quantisation; its creep, asymmetric loop and further modes are off "
        "(they are effects added in turn). Each cell adds one effect: creep, a second mode "
        "and the asymmetric loop at the plant's drawn parameters where it drew them (else the "
        "simulator's defaults), drift, saturation, backlash, dead zone and rate dependence at "
        "the simulator's defaults. The start declares the hysteresis "
        "(`model=linear model.effects=[hysteresis]`); `loop.max_rounds=1`; the drift cell "
        "diagnoses a 10 s held input, as in "
        "[undeclared_effects.md](undeclared_effects.md), whose rule and ceiling judge each "
        "cell (`undeclared_effects.case_row`): named as the top significant effect where its "
        "own output holds ≥ 5 % (`loop.min_score`) of the round-0 residual; at least half "
        "the ceiling taken off every test where it acts (> 0.05 µm RMS); no other test > 5 % "
        "worse; drift named, no gain claimed; below 5 % of the residual and < 10 % of every "
        "test's error, held by the start (PASS); otherwise unnamed is n/a (not a pass). "
        f"Asymmetry is named by {'/'.join(asymmetry_names())}"
        + ("" if asymmetry_names() == ("asymmetry",) else
           " (the catalogue has no asymmetry effect: static-law stand-ins)") + ".",
        "",
        "*Start misfit*: the declared start fitted to the base plant (the effect not added, "
        "`loop.max_rounds=0`): its mean free-run RMSE over the plant's noise σ, and on the "
        "tests where the effect acts, that error over the effect's own RMS (median, max). "
        "Above 1 the start's misfit of the plant is larger than the effect it should reveal. "
        "In brackets the structural part: a Bouc–Wen plant's exponent n ≠ 1, which the "
        "model's cell (exponent 1) cannot hold, as the noise-free RMSE over the twelve sines "
        "between the plant and its n = 1 cell of the same α and saturated state, over σ "
        "(`benchmarks/zoo.py`'s `gap_sizes`); a Prandtl–Ishlinskii cell is outside the "
        "model's class altogether.",
        "",
        f"**Pass share: {good} of {total} cells ({share})**; the issue asks for ≥ 80 % of "
        "plant × effect cells with at least 5 plants per effect. Of these, "
        f"{sum(found(r) for r in values)} named the effect (and met the rule's cut where it "
        "predicts it); the others pass because the effect holds < 5 % of the round-0 "
        "residual and < 10 % of every test's error (the *why* column says where the start's "
        "misfit hides it).",
        "",
        f"{sum(r.get('extra') == list(QUICK) for r in values)} of {len(values)} cells (and "
        f"their base runs) ran with `--quick` (`{' '.join(QUICK)}`: the declared start grown "
        "only, one refit learning rate; about half the default loop's fits), "
        "as their commands show.",
        "",
        "| effect | seed | plant | σ (µm) | start misfit | top significant (score) "
        "| effect share | acting tests: before → after (refit; ceiling) | worst other "
        "| verdict | why (numbers) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in values:
        if "failed" in r:
            lines.append(f"| {r['effect']} | {r['seed']} | {plant_cell(r)} | "
                         f"{r['sigma_um']:.3g} | {masking_cell(r)} | – | – | – | – | "
                         f"failed: {r['failed']} | |")
            continue
        top = (f"{r['top']} ({100 * r['top_score']:.1f} %)" if r["significant"]
               else "none significant")
        lines.append(
            f"| {r['effect']} | {r['seed']} | {plant_cell(r)} | {r['sigma_um']:.3g} "
            f"| {masking_cell(r)} | {top} | {100 * r['effect_share_max']:.1f} % "
            f"| {_tests_cell(r)} | {_others_cell(r)} | {_verdict_cell(r)} | {why_cell(r)} |")
    by_effect = {}
    for r in values:
        by_effect.setdefault(r["effect"], []).append(r)
    lines += ["", "Per effect: cells that pass / cells run.", ""]
    lines += [f"- {e}: {statistics(by_effect[e])[0]} / {statistics(by_effect[e])[1]}"
              for e in EFFECTS if e in by_effect]
    if skipped:
        lines += ["", "Skipped (the effect is not in the simulator for that plant):", ""]
        lines += [f"- {s}" for s in skipped]
    lines += ["", "Per cell: command, date, wall time:", ""]
    lines += [f"- {r['seed']} + {r['effect']}: `{r['command']}`"
              + (f", {r['date']} UTC, {r['seconds']:.0f} s" if "date" in r else "")
              for r in values]
    return "\n".join(lines) + "\n"


def write_page(rows: dict[str, dict], skipped: list[str]) -> None:
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.with_suffix(".json").write_text(json.dumps(rows, indent=1) + "\n")
    OUT.write_text(render(rows, skipped))
    log.info("wrote %s (%d cells)", OUT, len(rows))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", type=int, default=5, help="plants per effect")
    parser.add_argument("--seed", type=int, default=0, help="the first plant's seed")
    parser.add_argument("--seeds", type=int, nargs="+", help="these plants (instead)")
    parser.add_argument("--effects", nargs="+", default=list(EFFECTS), choices=EFFECTS)
    parser.add_argument("--jobs", type=int, default=1, help="cells at a time")
    parser.add_argument("--rounds", type=int, default=1, help="loop.max_rounds")
    parser.add_argument("--root", type=Path, default=REPO / "outputs" / "undeclared_zoo")
    parser.add_argument("--quick", action="store_true",
                        help="lighter loop settings for a shared CPU: " + " ".join(QUICK))
    parser.add_argument("--render", action="store_true", help="only rewrite the page")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    cells, skipped = [], []
    for effect in args.effects:
        seeds = args.seeds or plants_for(effect, args.plants, args.seed)
        for seed in seeds:
            if added_block(seed, effect) is None:
                skipped.append(f"plant {seed} + {effect}: {why_skipped(seed, effect)}")
            else:
                cells.append((seed, effect))
    if not args.render:
        run_cells(cells, args.root, args.rounds, args.jobs, QUICK if args.quick else ())
    write_page(kept_rows(args.root), skipped)


if __name__ == "__main__":
    main()
