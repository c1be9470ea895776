"""The grey-box fitted two ways on zoo plants and on bundled data sets: error and CPU seconds.

    python benchmarks/greybox_pair.py --compare optimizer --cases plants,p885 --root /tmp/gbo
    python benchmarks/greybox_pair.py --compare feedthrough --seeds 0,1,2 --jobs 2 --root /tmp/gbf
    python benchmarks/greybox_pair.py --compare optimizer --root /tmp/gbo --render

``--compare`` names the pair (`COMPARISONS`): ``optimizer`` (Adam, the default, against
``training.optimizer=lbfgs``; ``docs/results/greybox_optimizer.md``), ``feedthrough`` (the
modes alone, ``model.feedthrough=false``, against the default's modes with a feedthrough
share; ``docs/results/greybox_feedthrough.md``) or ``exponent`` (the default against
``model.learn_exponent=true``; ``docs/results/greybox_exponent.md``; its first setting is
``feedthrough``'s second, so one root serves both). Each case is fitted through the console app
with ``model=greybox`` and default settings (a zoo plant through ``data=csv``, a bundled data
set with the accuracy table's settings, `greybox_asymmetry.BUNDLED`), once per setting; a fit
found in the root is reused. The page gives the mean free-run RMSE over the test recordings
(over the plant's noise σ for the zoo), the process's CPU seconds (one core) and the
validation free-run loss of the model kept.
"""

from __future__ import annotations

import argparse
import datetime
import json
import logging
import re
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from greybox_asymmetry import BUNDLED, data_overrides
from greybox_structure import PROCESS_CPU, page_header, train_greybox

REPO = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Setting:
    """One way to fit: its folder name, its label on the page and its overrides."""

    name: str
    label: str
    overrides: tuple[str, ...]


@dataclass(frozen=True)
class Comparison:
    """Two settings, the page they are compared on and what the page says they are."""

    title: str
    page: str
    base: Setting
    variant: Setting
    what: str


COMPARISONS = {
    "optimizer": Comparison(
        "The grey-box with Adam and with L-BFGS", "greybox_optimizer.md",
        Setting("adam", "Adam", ()), Setting("lbfgs", "L-BFGS", ("training.optimizer=lbfgs",)),
        "once with Adam (the default) and once with `training.optimizer=lbfgs`"),
    "feedthrough": Comparison(
        "The grey-box's modes with and without a feedthrough", "greybox_feedthrough.md",
        Setting("modes_alone", "modes alone", ("model.feedthrough=false",)),
        Setting("feedthrough", "feedthrough", ()),
        "once with the modes alone (`model.feedthrough=false`) and once with the default's "
        "feedthrough share beside them (the residual stiffness of modes above the modelled "
        "ones, learned from 0)"),
    "exponent": Comparison(
        "The grey-box's Bouc–Wen cell with its exponent fixed at 1 and learned",
        "greybox_exponent.md",
        Setting("feedthrough", "exponent 1", ()),
        Setting("learn_exponent", "exponent learned", ("model.learn_exponent=true",)),
        "once with the Bouc–Wen cell's exponent at 1 and once with `model.learn_exponent=true` "
        "(the exponent learned from 1; `model.hysteresis=auto` still chooses the cell, a "
        "Prandtl–Ishlinskii cell has none)"),
}

#: a change of error within this share counts as none
SAME = 0.005

log = logging.getLogger("greybox_pair")


def fit(case: str, setting: Setting, root: Path) -> Path:
    """``case`` fitted with ``setting`` into its folder (reused when done)."""
    folder = root / case / setting.name
    if (folder / "metrics.json").is_file():
        return folder
    data = ["data=default"] if case == "default" else data_overrides(case, root)
    cpu = train_greybox([*setting.overrides, *data], folder)
    (folder / "cputime").write_text(f"{cpu:.1f}\n")
    return folder


def row(case: str, pair: Comparison, root: Path) -> dict[str, Any]:
    """A case's noise σ (zoo plants) and, per setting, its mean RMSE, validation loss and
    CPU seconds."""
    out: dict[str, Any] = {"case": case, "sigma": None}
    plant = root / case / "data" / "plant.json"
    if plant.is_file():
        out["sigma"] = json.loads(plant.read_text())["effects"]["noise"]["rms_um"]
    for setting in (pair.base, pair.variant):
        folder = root / case / setting.name
        metrics = json.loads((folder / "metrics.json").read_text())
        cputime = folder / "cputime"
        out[setting.name] = {
            "rmse": float(np.mean([m["rmse_free_run"] for m in metrics["tests"].values()])),
            "val": metrics.get("val_mse_scaled"),
            "cpu_s": float(cputime.read_text().split()[0]) if cputime.is_file() else None,
            "wall_s": log_span(folder / "fit.log"),
        }
    return out


def log_span(path: Path) -> float:
    """Seconds from a run log's first stamped line to its last."""
    stamps = re.findall(r"^\[(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d+)\]", path.read_text(),
                        flags=re.MULTILINE)
    first, last = (datetime.datetime.strptime(t, "%Y-%m-%d %H:%M:%S,%f")
                   for t in (stamps[0], stamps[-1]))
    return (last - first).total_seconds()


def time_column(rows: list[dict[str, Any]], pair: Comparison) -> tuple[str, str, str]:
    """Which time the page shows: each process's CPU seconds where every fit has them, else
    each run's wall seconds from its log; its column label, key and the page's clock."""
    fits = [r[s.name] for r in rows for s in (pair.base, pair.variant)]
    if all(f["cpu_s"] is not None for f in fits):
        return "CPU s", "cpu_s", PROCESS_CPU
    return ("wall s", "wall_s", "wall seconds of each run, its log's first line to its last: "
            "two fits side by side on the 2 cores, so close to each one's CPU seconds")


def render(rows: list[dict[str, Any]], pair: Comparison, command: str) -> str:
    """The page."""
    a, b = pair.base, pair.variant
    label, key, clock = time_column(rows, pair)
    lines = [
        *page_header(pair.title, command, clock),
        "Each case fitted with `model=greybox` and its defaults (zoo plants through "
        f"`data=csv`, bundled data sets with the accuracy table's settings), {pair.what}. "
        "Score: mean free-run RMSE over the test recordings (over the plant's noise σ for the "
        "zoo; a bundled data set's in its units); validation: the kept model's validation "
        "free-run MSE (scaled).",
        "",
        f"| case | {a.label} | {b.label} | change | validation {a.label} | validation "
        f"{b.label} | {label} {a.label} | {label} {b.label} |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        first, second = r[a.name], r[b.name]
        unit = (lambda x: f"{x:.4g}") if r["sigma"] is None else \
            (lambda x, s=r["sigma"]: f"{x / s:.3g} σ")
        lines.append(
            f"| {r['case']} | {unit(first['rmse'])} | {unit(second['rmse'])} "
            f"| {100 * (second['rmse'] / first['rmse'] - 1):+.1f} % | {first['val']:.3e} "
            f"| {second['val']:.3e} | {first[key]:.0f} | {second[key]:.0f} |")
    lines += ["", summary(rows, pair, key, label), ""]
    return "\n".join(lines)


def summary(rows: list[dict[str, Any]], pair: Comparison, key: str, label: str) -> str:
    """The median change of error and time, and on how many cases the variant was better."""
    a, b = pair.base, pair.variant
    error = [r[b.name]["rmse"] / r[a.name]["rmse"] - 1 for r in rows]
    cpu = [r[b.name][key] / r[a.name][key] for r in rows]
    better = sum(e < -SAME for e in error)
    worse = sum(e > SAME for e in error)
    load = (" Wall seconds count the waits for a core under the machine's load at the time "
            "of each run." if key == "wall_s" else "")
    return (f"{b.label} against {a.label} over {len(rows)} cases: median error change "
            f"{100 * float(np.median(error)):+.1f} % (better on {better}, worse on {worse}, "
            f"within {100 * SAME:.1f} % on {len(rows) - better - worse}; from "
            f"{100 * min(error):+.1f} % to {100 * max(error):+.1f} %), median "
            f"{label.split()[0]} time {float(np.median(cpu)):.2f} × {a.label}'s.{load}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--compare", choices=sorted(COMPARISONS), required=True)
    parser.add_argument("--seeds", default="0,1,2,3,4")
    parser.add_argument("--cases", default="plants,default",
                        help=f"which to fit: plants (the seeds), default, {', '.join(BUNDLED)}")
    parser.add_argument("--root", type=Path, default=None,
                        help="where the fits go (default: outputs/greybox_<compare>)")
    parser.add_argument("--jobs", type=int, default=1, help="fits at once (one core each)")
    parser.add_argument("--render", action="store_true", help="only rewrite the page")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    pair = COMPARISONS[args.compare]
    root = args.root or Path(f"outputs/greybox_{args.compare}")
    chosen = args.cases.split(",")
    cases = ([f"plant_{int(s)}" for s in args.seeds.split(",")] if "plants" in chosen else [])
    cases += [c for c in ["default", *BUNDLED] if c in chosen]
    if not args.render:
        for case in cases:  # export each plant once, before fits run side by side
            if case != "default":
                data_overrides(case, root)
        jobs = [(case, setting) for case in cases for setting in (pair.base, pair.variant)]
        with ThreadPoolExecutor(max(1, args.jobs)) as pool:
            for (case, setting), folder in zip(
                    jobs, pool.map(lambda job: fit(job[0], job[1], root), jobs), strict=True):
                log.info("%s: %s -> %s", case, setting.name, folder)
    done = [c for c in cases if all((root / c / s.name / "metrics.json").is_file()
                                    for s in (pair.base, pair.variant))]
    out = REPO / "docs" / "results" / pair.page
    out.write_text(render([row(c, pair, root) for c in done], pair,
                          f"python benchmarks/greybox_pair.py --compare {args.compare} --seeds "
                          f"{args.seeds} --cases {args.cases} --root <root>") + "\n")
    log.info("wrote %s", out)


if __name__ == "__main__":
    main()
