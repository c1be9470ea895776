"""The grey-box with and without the asymmetric loop's square law, on zoo plants and on the
default simulator.

    python benchmarks/greybox_asymmetry.py --seeds 0,1,4,6,7 --root /tmp/gba
    python benchmarks/greybox_asymmetry.py --seeds 4,6 --cases plants --root /tmp/gba  # some
    python benchmarks/greybox_asymmetry.py --root /tmp/gba --render     # only rewrite the page

Each zoo plant (`hysteresis_lab.sim.zoo.export_zoo_plant`) is fitted through ``data=csv``
with ``model=greybox`` twice: with ``model.effects=[]`` (*symmetric*) and with
``model.effects=[asymmetry]`` (the square law on its hysteresis cell, grown from zero weight);
so is the bundled default simulator (``data=default``), as it is (*default*) and with
``creep`` declared in both settings (*default_creep*, the accuracy table's grey-box). A fit
done before (its ``metrics.json`` in ``<root>/<case>/<setting>``) is reused, and so is a
plant's exported data (``<root>/plant_<seed>/data``). The page,
``docs/results/greybox_asymmetry.md``, gives the mean free-run RMSE over the twelve test
sines (over the plant's noise σ for the zoo), the square law's share of the cell's response
in the plant and in the fit, the process's CPU seconds (one core: ``OMP_NUM_THREADS=1``) and
whether the square law belongs in the defaults (`verdict`).
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
from greybox_structure import page_header, train_greybox

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "results" / "greybox_asymmetry.md"
#: the two settings compared: name -> the effects added to the case's
SETTINGS = {"symmetric": [], "asymmetry": ["asymmetry"]}
#: the bundled simulator's cases: name -> the effects declared in both settings (the
#: accuracy table's grey-box declares creep, which the bundled plant has)
DEFAULTS = {"default": [], "default_creep": ["creep"]}
#: the other bundled data sets the accuracy table fits the grey-box on: name -> its settings
#: there (`benchmarks/accuracy.py`); the default would reach them too
BUNDLED = {
    "bouc_wen": ["data=bouc_wen"],
    "cascaded_tanks": ["data=cascaded_tanks"],
    "emps": ["data=emps"],
    "p885": ["data=p885"],
    "fsm": ["data=fsm", "model.n_modes=14", "training.lr=5e-4", "model.recording_repeats=2",
            "trainer.max_epochs=10"],
}
#: the simulator's stroke in its asymmetry law (``c * 40 µm * (v / v_ref)^2``)
STROKE_UM = 40.0
#: a fitted square law below this share of the cell's response does next to nothing
IDLE_SHARE = 0.005
#: a cost above this share on a plant without a strong asymmetric loop keeps it opt-in
COST_LIMIT = 0.03

log = logging.getLogger("greybox_asymmetry")


def data_overrides(case: str, root: Path) -> list[str]:
    """The data settings of a case: the default simulator, or a zoo plant's CSV files."""
    if case in DEFAULTS:
        return ["data=default"]
    if case in BUNDLED:
        return BUNDLED[case]
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
    effects = [*DEFAULTS.get(case, []), *SETTINGS[setting]]
    cpu = train_greybox([f"model.effects=[{','.join(effects)}]", *data], folder)
    (folder / "cputime").write_text(f"{cpu:.1f}\n")
    return folder


def _square_share(folder: Path) -> float | None:
    """The fitted square law over the cell's linear slope, ``q / d`` (the square term's
    share of the cell's linear response at the training amplitude); None: none fitted."""
    from hysteresis_lab.models.io import load_model

    params = load_model(folder / "model.ckpt").physical_parameters()
    if "asymmetry" not in params:
        return None
    return params["asymmetry"]["weight"] / params["hysteresis"]["d"]


def row(case: str, root: Path) -> dict[str, Any]:
    """A case's plant facts and, per setting, its mean RMSE, weight and CPU seconds."""
    out: dict[str, Any] = {"case": case}
    if case in DEFAULTS:
        declared = "".join(f", `model.effects=[{e}]`" for e in DEFAULTS[case])
        out.update(sigma=None, coefficient=0.0, share=0.0,
                   plant=f"bundled simulator{declared}")
    elif case in BUNDLED:
        out.update(sigma=None, coefficient=None, share=None, plant="bundled data set")
    else:
        plant = json.loads((root / case / "data" / "plant.json").read_text())
        effect = plant["effects"].get("asymmetry", {})
        coefficient = effect.get("coefficient", 0.0) if effect.get("enabled") else 0.0
        # the simulator's square term over the cell's linear response at v_ref
        share = coefficient * STROKE_UM / (plant["description"]["d_um_per_v"]
                                           * effect.get("v_ref", 100.0))
        out.update(sigma=plant["effects"]["noise"]["rms_um"], coefficient=coefficient,
                   share=share, plant=plant["description"]["cell"])
    for setting in SETTINGS:
        folder = root / case / setting
        metrics = json.loads((folder / "metrics.json").read_text())
        rmse = float(np.mean([m["rmse_free_run"] for m in metrics["tests"].values()]))
        out[setting] = {"rmse": rmse, "share": _square_share(folder),
                        "cpu_s": float((folder / "cputime").read_text().split()[0])}
    return out


def render(rows: list[dict[str, Any]], command: str) -> str:
    """The page."""
    lines = [
        *page_header("The grey-box with the asymmetric loop's square law", command),
        "Each case fitted with `model=greybox` (zoo plants through `data=csv`, the bundled "
        "simulator and the other bundled data sets through `data=<name>` with the accuracy "
        "table's settings): *symmetric* with `model.effects=[]` (the bundled simulator also "
        "with `[creep]`, as in the accuracy table), *asymmetry* with `asymmetry` declared "
        "too (a square law `q A (v / A)^2` of the hysteresis cell's input added to its "
        "output, grown from `q = 0`). Score: mean free-run RMSE over the test recordings "
        "(the twelve ±100 V sines of the simulator and the zoo, over the plant's noise σ "
        "for the zoo; a bundled data set's in its units). Square law: its "
        "share of the cell's linear response at full drive, the plant's `40 µm · c / "
        "(d · v_ref)` (the simulator adds `c · 40 µm · (v / v_ref)^2` to `d v`; 0: none) "
        "and the fit's `q / d`.", "",
        "| case | plant cell | square law: plant | learned | symmetric | asymmetry | change "
        "| CPU s sym. | CPU s asym. |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        sym, asym = r["symmetric"], r["asymmetry"]
        unit = (lambda x: f"{x:.4g}") if r["coefficient"] is None else \
            (lambda x: f"{x:.4g} µm") if r["sigma"] is None else \
            (lambda x, s=r["sigma"]: f"{x / s:.3g} σ")
        plant = "" if r["share"] is None else f"{r['share']:+.3f}"
        change = asym["rmse"] / sym["rmse"] - 1.0
        learned = "" if asym["share"] is None else f"{asym['share']:+.3f}"
        lines.append(
            f"| {r['case']} | {r['plant']} | {plant} | {learned} "
            f"| {unit(sym['rmse'])} | {unit(asym['rmse'])} | {100 * change:+.1f} % "
            f"| {sym['cpu_s']:.0f} | {asym['cpu_s']:.0f} |")
    lines += ["", verdict(rows), "", _notes(rows), ""]
    return "\n".join(lines)


def _notes(rows: list[dict[str, Any]]) -> str:
    """What the changes do not come from, and what the square law costs in CPU."""
    idle = [r["case"] for r in rows if r["asymmetry"]["share"] is not None
            and abs(r["asymmetry"]["share"]) < IDLE_SHARE]
    cpu = [r["asymmetry"]["cpu_s"] / r["symmetric"]["cpu_s"] - 1.0 for r in rows]
    return (f"Where the fit leaves the square law near zero (|q / d| < {IDLE_SHARE}: "
            f"{', '.join(idle) or 'none'}) a change is the grown stage's extra refit, not the "
            "law. Declared, the square law is one more grown stage (`model.grow`): "
            f"{100 * min(cpu):.0f}–{100 * max(cpu):.0f} % more CPU per fit here.")


def verdict(rows: list[dict[str, Any]]) -> str:
    """Whether the square law belongs in the defaults: it must help every plant with an
    asymmetric loop and cost the default simulator and the plants without one no more than
    `COST_LIMIT`."""
    change = {r["case"]: r["asymmetry"]["rmse"] / r["symmetric"]["rmse"] - 1.0 for r in rows}
    asymmetric = [r["case"] for r in rows if r["coefficient"] not in (None, 0)]
    symmetric = [r["case"] for r in rows if r["coefficient"] == 0]
    others = [r["case"] for r in rows if r["coefficient"] is None]
    helps = all(change[c] < 0 for c in asymmetric)
    costs = max((change[c] for c in symmetric + others), default=0.0)
    default = helps and costs <= COST_LIMIT

    def listed(cases: list[str]) -> str:
        return ", ".join(f"{c} {100 * change[c]:+.1f} %" for c in cases) or "none"

    return (f"Asymmetric plants: {listed(asymmetric)}; without an asymmetric loop: "
            f"{listed(symmetric)}; other bundled data sets: {listed(others)}. "
            + ("It helps every asymmetric plant and costs the others at most "
               f"{100 * COST_LIMIT:.0f} %: a default." if default else
               "Not a default (it must help every asymmetric plant and cost the others at "
               f"most {100 * COST_LIMIT:.0f} %): opt-in, `model.effects=[asymmetry]`."))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0,1,4,6,7")
    parser.add_argument("--cases", default=",".join(["plants", *DEFAULTS]),
                        help="which to fit: plants (the seeds), default, default_creep (the "
                             f"bundled simulator without and with creep declared), "
                             f"{', '.join(BUNDLED)}")
    parser.add_argument("--root", type=Path, default=Path("outputs/greybox_asymmetry"))
    parser.add_argument("--settings", default=",".join(SETTINGS),
                        help="the settings to fit (the page needs both)")
    parser.add_argument("--render", action="store_true", help="only rewrite the page")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    plants = [f"plant_{int(s)}" for s in args.seeds.split(",")]
    if not args.render:
        chosen = args.cases.split(",")
        cases = (plants if "plants" in chosen else []) + [c for c in [*DEFAULTS, *BUNDLED]
                                                          if c in chosen]
        for case in cases:
            for setting in args.settings.split(","):
                log.info("%s: %s -> %s", case, setting, fit(case, setting, args.root))
    done = [c for c in BUNDLED if (args.root / c / "asymmetry" / "metrics.json").is_file()
            and (args.root / c / "symmetric" / "metrics.json").is_file()]
    rows = [row(case, args.root) for case in [*plants, *DEFAULTS, *done]]
    OUT.write_text(render(rows, "python benchmarks/greybox_asymmetry.py --seeds "
                          f"{args.seeds} --root <root>") + "\n")
    log.info("wrote %s", OUT)


if __name__ == "__main__":
    main()
