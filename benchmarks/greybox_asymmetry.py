"""The grey-box with and without the asymmetric loop's square law, on zoo plants and on the
default simulator.

    python benchmarks/greybox_asymmetry.py --seeds 0,1,4,6,7 --root /tmp/gba
    python benchmarks/greybox_asymmetry.py --seeds 4,6 --cases plants --root /tmp/gba  # some
    python benchmarks/greybox_asymmetry.py --root /tmp/gba --render     # only rewrite the page

Each zoo plant (`hysteresis_lab.sim.zoo.export_zoo_plant`) is fitted through ``data=csv``
with ``model=greybox`` twice: with its defaults (*symmetric*) and with
``model.effects=[asymmetry]`` (the square law on its hysteresis cell, grown from zero weight);
so is the bundled default simulator (``data=default``). A fit done before (its
``metrics.json`` in ``<root>/<case>/<setting>``) is reused, and so is a plant's exported data
(``<root>/plant_<seed>/data``). The page, ``docs/results/greybox_asymmetry.md``, gives the
mean free-run RMSE over the twelve test sines (over the plant's noise σ for the zoo), the
learned square-law weight and the process's CPU seconds (one core: ``OMP_NUM_THREADS=1``).
"""

from __future__ import annotations

import argparse
import datetime
import json
import logging
import os
import resource
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "results" / "greybox_asymmetry.md"
#: the two settings compared: name -> model overrides
SETTINGS = {"symmetric": [], "asymmetry": ["model.effects=[asymmetry]"]}
#: the bundled simulator's case folder
DEFAULT = "default"
#: a cost above this share on a plant without a strong asymmetric loop keeps it opt-in
COST_LIMIT = 0.03
QUIET = ["logger=none", "trainer.enable_progress_bar=false"]

log = logging.getLogger("greybox_asymmetry")


def data_overrides(case: str, root: Path) -> list[str]:
    """The data settings of a case: the default simulator, or a zoo plant's CSV files."""
    if case == DEFAULT:
        return ["data=default"]
    from hysteresis_lab.sim.zoo import export_zoo_plant

    seed = int(case.removeprefix("plant_"))
    data = root / case / "data"
    if (data / "plant.json").is_file():
        tests = sorted(str(p) for p in data.glob("test_*.csv"))
        files = {"train": str(data / "train.csv"), "val": str(data / "val.csv"), "test": tests}
    else:
        files = export_zoo_plant(seed, data)
    return ["data=csv", f"data.train={files['train']}", f"data.val={files['val']}",
            f"data.test=[{','.join(files['test'])}]"]


def fit(case: str, setting: str, root: Path) -> Path:
    """``case`` fitted with ``setting`` into its folder (reused when done)."""
    folder = root / case / setting
    if (folder / "metrics.json").is_file():
        return folder
    data = data_overrides(case, root)
    folder.mkdir(parents=True, exist_ok=True)
    command = [str(Path(sys.executable).parent / "hysteresis-lab-train"), "model=greybox",
               *SETTINGS[setting], *data, *QUIET, f"hydra.run.dir={folder}"]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    with (folder / "fit.log").open("w") as handle:
        subprocess.run(command, cwd=REPO, env=env, stdout=handle, stderr=subprocess.STDOUT,
                       check=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    (folder / "cputime").write_text(f"{cpu:.1f}\n")
    return folder


def _square_weight(folder: Path) -> float | None:
    """The fitted square-law weight (None: the model has none)."""
    from hysteresis_lab.models.io import load_model

    params = load_model(folder / "model.ckpt").physical_parameters()
    return params["asymmetry"]["weight"] if "asymmetry" in params else None


def row(case: str, root: Path) -> dict[str, Any]:
    """A case's plant facts and, per setting, its mean RMSE, weight and CPU seconds."""
    out: dict[str, Any] = {"case": case}
    if case == DEFAULT:
        out.update(sigma=None, asymmetry=0.0, plant="bundled default simulator")
    else:
        plant = json.loads((root / case / "data" / "plant.json").read_text())
        effect = plant["effects"].get("asymmetry", {})
        out.update(sigma=plant["effects"]["noise"]["rms_um"],
                   asymmetry=effect.get("coefficient", 0.0) if effect.get("enabled") else 0.0,
                   plant=plant["description"]["cell"])
    for setting in SETTINGS:
        folder = root / case / setting
        metrics = json.loads((folder / "metrics.json").read_text())
        rmse = float(np.mean([m["rmse_free_run"] for m in metrics["tests"].values()]))
        out[setting] = {"rmse": rmse, "weight": _square_weight(folder),
                        "cpu_s": float((folder / "cputime").read_text().split()[0])}
    return out


def render(rows: list[dict[str, Any]], command: str) -> str:
    """The page."""
    from hysteresis_lab.evaluation.provenance import commit_stamp

    lines = [
        "# The grey-box with the asymmetric loop's square law", "",
        f"Command: `{command}`; commit `{commit_stamp(REPO)}`; "
        f"{datetime.date.today().isoformat()}; shared 2-core CPU, one core per fit "
        "(`OMP_NUM_THREADS=1`; CPU seconds of the whole `hysteresis-lab-train` process). "
        "Fits found in the root are reused: the commit is the page's, a reused fit's may be "
        "older.", "",
        "Each case fitted with `model=greybox` (zoo plants through `data=csv`, the bundled "
        "simulator through `data=default`): *symmetric* with its defaults, *asymmetry* with "
        "`model.effects=[asymmetry]` (a square law `q A (v / A)^2` of the hysteresis cell's "
        "input added to its output, grown from `q = 0`). Score: mean free-run RMSE over the "
        "twelve ±100 V test sines, over the plant's noise σ for the zoo. Plant asymmetry: "
        "the simulator's coefficient `c` (`c · 40 µm · (v / 100 V)^2` added to the "
        "displacement; 0: none).", "",
        "| case | plant cell | plant asymmetry c | symmetric | asymmetry | change "
        "| learned q | CPU s sym. | CPU s asym. |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        sym, asym = r["symmetric"], r["asymmetry"]
        unit = (lambda x: f"{x:.4g} µm") if r["sigma"] is None else \
            (lambda x, s=r["sigma"]: f"{x / s:.3g} σ")
        change = asym["rmse"] / sym["rmse"] - 1.0
        weight = "" if asym["weight"] is None else f"{asym['weight']:.3g}"
        lines.append(
            f"| {r['case']} | {r['plant']} | {r['asymmetry']:.3g} | {unit(sym['rmse'])} "
            f"| {unit(asym['rmse'])} | {100 * change:+.1f} % | {weight} "
            f"| {sym['cpu_s']:.0f} | {asym['cpu_s']:.0f} |")
    lines += ["", verdict(rows), ""]
    return "\n".join(lines)


def verdict(rows: list[dict[str, Any]]) -> str:
    """Whether the square law belongs in the defaults: it must help every plant with an
    asymmetric loop and cost the default simulator and the plants without one no more than
    `COST_LIMIT`."""
    change = {r["case"]: r["asymmetry"]["rmse"] / r["symmetric"]["rmse"] - 1.0 for r in rows}
    asymmetric = [r["case"] for r in rows if abs(r["asymmetry"]) > 0]
    symmetric = [r["case"] for r in rows if r["asymmetry"] == 0]
    helps = all(change[c] < 0 for c in asymmetric)
    costs = max((change[c] for c in symmetric), default=0.0)
    default = helps and costs <= COST_LIMIT
    return (f"Asymmetric plants: {', '.join(f'{c} {100 * change[c]:+.1f} %' for c in asymmetric)}"
            f"; without an asymmetric loop: "
            f"{', '.join(f'{c} {100 * change[c]:+.1f} %' for c in symmetric)}. "
            + ("It helps every asymmetric plant and costs the others at most "
               f"{100 * COST_LIMIT:.0f} %: a default." if default else
               "Not a default (it must help every asymmetric plant and cost the others at "
               f"most {100 * COST_LIMIT:.0f} %): opt-in, `model.effects=[asymmetry]`."))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0,1,4,6,7")
    parser.add_argument("--cases", default="plants,default",
                        help="which to fit: plants (the seeds), default (the simulator)")
    parser.add_argument("--root", type=Path, default=Path("outputs/greybox_asymmetry"))
    parser.add_argument("--settings", default=",".join(SETTINGS),
                        help="the settings to fit (the page needs both)")
    parser.add_argument("--render", action="store_true", help="only rewrite the page")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    plants = [f"plant_{int(s)}" for s in args.seeds.split(",")]
    if not args.render:
        chosen = args.cases.split(",")
        cases = (plants if "plants" in chosen else []) + ([DEFAULT] if DEFAULT in chosen
                                                          else [])
        for case in cases:
            for setting in args.settings.split(","):
                log.info("%s: %s -> %s", case, setting, fit(case, setting, args.root))
    rows = [row(case, args.root) for case in [*plants, DEFAULT]]
    OUT.write_text(render(rows, "python benchmarks/greybox_asymmetry.py --seeds "
                          f"{args.seeds} --root <root>") + "\n")
    log.info("wrote %s", OUT)


if __name__ == "__main__":
    main()
