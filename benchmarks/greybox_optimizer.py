"""The grey-box trained with Adam (its default) and with L-BFGS (``training.optimizer=lbfgs``),
on zoo plants and on bundled data sets: error and CPU seconds.

    python benchmarks/greybox_optimizer.py --cases plants,default,p885 --root /tmp/gbo
    python benchmarks/greybox_optimizer.py --seeds 0,1,2,3,4 --root /tmp/gbo --render

Each case is fitted through the console app with ``model=greybox`` and default settings (a zoo
plant through ``data=csv``, a bundled data set with the accuracy table's settings,
`greybox_asymmetry.BUNDLED`), once per optimiser. A fit found in the root is reused. The
page, ``docs/results/greybox_optimizer.md``, gives the mean free-run RMSE over the test
recordings (over the plant's noise σ for the zoo), the process's CPU seconds (one core) and
the validation free-run loss of the model kept.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
from greybox_asymmetry import BUNDLED, data_overrides
from greybox_structure import page_header, train_greybox

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "results" / "greybox_optimizer.md"
#: the optimisers compared: name -> its overrides
SETTINGS = {"adam": [], "lbfgs": ["training.optimizer=lbfgs"]}

log = logging.getLogger("greybox_optimizer")


def fit(case: str, setting: str, root: Path) -> Path:
    """``case`` fitted with ``setting`` into its folder (reused when done)."""
    folder = root / case / setting
    if (folder / "metrics.json").is_file():
        return folder
    data = ["data=default"] if case == "default" else data_overrides(case, root)
    cpu = train_greybox([*SETTINGS[setting], *data], folder)
    (folder / "cputime").write_text(f"{cpu:.1f}\n")
    return folder


def row(case: str, root: Path) -> dict[str, Any]:
    """A case's noise σ (zoo plants) and, per optimiser, its mean RMSE, validation loss and
    CPU seconds."""
    out: dict[str, Any] = {"case": case, "sigma": None}
    plant = root / case / "data" / "plant.json"
    if plant.is_file():
        out["sigma"] = json.loads(plant.read_text())["effects"]["noise"]["rms_um"]
    for setting in SETTINGS:
        folder = root / case / setting
        metrics = json.loads((folder / "metrics.json").read_text())
        out[setting] = {
            "rmse": float(np.mean([m["rmse_free_run"] for m in metrics["tests"].values()])),
            "val": metrics.get("val_mse_scaled"),
            "cpu_s": float((folder / "cputime").read_text().split()[0]),
        }
    return out


def render(rows: list[dict[str, Any]], command: str) -> str:
    """The page."""
    lines = [
        *page_header("The grey-box with Adam and with L-BFGS", command),
        "Each case fitted with `model=greybox` and its defaults (zoo plants through "
        "`data=csv`, bundled data sets with the accuracy table's settings), once with Adam "
        "(the default) and once with `training.optimizer=lbfgs`. Score: mean free-run RMSE "
        "over the test recordings (over the plant's noise σ for the zoo; a bundled data "
        "set's in its units); validation: the kept model's validation free-run MSE (scaled).",
        "",
        "| case | Adam | L-BFGS | change | validation Adam | validation L-BFGS "
        "| CPU s Adam | CPU s L-BFGS |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        adam, lbfgs = r["adam"], r["lbfgs"]
        unit = (lambda x: f"{x:.4g}") if r["sigma"] is None else \
            (lambda x, s=r["sigma"]: f"{x / s:.3g} σ")
        lines.append(
            f"| {r['case']} | {unit(adam['rmse'])} | {unit(lbfgs['rmse'])} "
            f"| {100 * (lbfgs['rmse'] / adam['rmse'] - 1):+.1f} % | {adam['val']:.3e} "
            f"| {lbfgs['val']:.3e} | {adam['cpu_s']:.0f} | {lbfgs['cpu_s']:.0f} |")
    lines += ["", summary(rows), ""]
    return "\n".join(lines)


def summary(rows: list[dict[str, Any]]) -> str:
    """The median change of error and CPU, and on how many cases L-BFGS was better."""
    error = [r["lbfgs"]["rmse"] / r["adam"]["rmse"] - 1 for r in rows]
    cpu = [r["lbfgs"]["cpu_s"] / r["adam"]["cpu_s"] for r in rows]
    better = sum(e < 0 for e in error)
    return (f"L-BFGS against Adam over {len(rows)} cases: median error change "
            f"{100 * float(np.median(error)):+.1f} % (better on {better}, worse on "
            f"{len(rows) - better}; from {100 * min(error):+.1f} % to {100 * max(error):+.1f} "
            f"%), median CPU {float(np.median(cpu)):.2f} × Adam's.")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0,1,2,3,4")
    parser.add_argument("--cases", default="plants,default",
                        help=f"which to fit: plants (the seeds), default, {', '.join(BUNDLED)}")
    parser.add_argument("--root", type=Path, default=Path("outputs/greybox_optimizer"))
    parser.add_argument("--render", action="store_true", help="only rewrite the page")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    chosen = args.cases.split(",")
    cases = ([f"plant_{int(s)}" for s in args.seeds.split(",")] if "plants" in chosen else [])
    cases += [c for c in ["default", *BUNDLED] if c in chosen]
    if not args.render:
        for case in cases:
            for setting in SETTINGS:
                log.info("%s: %s -> %s", case, setting, fit(case, setting, args.root))
    done = [c for c in cases if all((args.root / c / s / "metrics.json").is_file()
                                    for s in SETTINGS)]
    OUT.write_text(render([row(c, args.root) for c in done],
                          f"python benchmarks/greybox_optimizer.py --seeds {args.seeds} "
                          f"--cases {args.cases} --root <root>") + "\n")
    log.info("wrote %s", OUT)


if __name__ == "__main__":
    main()
