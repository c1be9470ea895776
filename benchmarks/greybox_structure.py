"""The grey-box on zoo plants, settings side by side: its delay and modes chosen from the
data (``--compare structure``), or its hysteresis cell (``--compare cell``).

    python benchmarks/greybox_structure.py --seeds 0,1,4,6,7 --root /tmp/gbs
    python benchmarks/greybox_structure.py --compare cell --seeds 2,3,4,5,10,11 --root /tmp/gbc
    python benchmarks/greybox_structure.py --root /tmp/gbs --render     # only rewrite the page

Each zoo plant (`hysteresis_lab.sim.zoo.export_zoo_plant`) is fitted through ``data=csv`` with
``model=greybox`` once per setting. *structure*: the former fixed structure
(``model.delay=1 model.n_modes=1``) against the defaults (``auto``: chosen from the training
data); page ``docs/results/greybox_structure.md``. *cell*: the Bouc–Wen cell, Prandtl–Ishlinskii
play operators (``model.hysteresis=prandtl_ishlinskii``) and the cell chosen from the data
(``model.hysteresis=auto``), each symmetric (``model.effects=[]``); page
``docs/results/greybox_cell.md``. A fit done before (its ``metrics.json`` in
``<root>/plant_<seed>/<setting>``) is reused. Each page gives per plant the free-run RMSE over
the plant's noise σ (mean of the twelve test sines) and the process's CPU seconds (one core:
``OMP_NUM_THREADS=1``).
"""

from __future__ import annotations

import argparse
import datetime
import json
import logging
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "docs" / "results"
#: per comparison, the two settings compared: name -> model overrides
COMPARISONS: dict[str, dict[str, list[str]]] = {
    "structure": {"fixed": ["model.delay=1", "model.n_modes=1"], "auto": []},
    # the symmetric cell (``model.effects=[]``): the cells compared alone
    "cell": {"bouc_wen": ["model.hysteresis=bouc_wen", "model.effects=[]"],
             "prandtl_ishlinskii": ["model.hysteresis=prandtl_ishlinskii", "model.effects=[]"],
             "auto": ["model.hysteresis=auto", "model.effects=[]"]},
}
QUIET = ["logger=none", "trainer.enable_progress_bar=false"]

log = logging.getLogger("greybox_structure")


def fit(seed: int, setting: str, overrides: list[str], root: Path) -> Path:
    """Plant ``seed`` fitted with ``setting`` (its model ``overrides``) into its folder
    (reused when done)."""
    from hysteresis_lab.sim.zoo import export_zoo_plant

    folder = root / f"plant_{seed}" / setting
    if (folder / "metrics.json").is_file():
        return folder
    files = export_zoo_plant(seed, root / f"plant_{seed}" / "data")
    cpu = train_greybox([*overrides, "data=csv", f"data.train={files['train']}",
                         f"data.val={files['val']}", f"data.test=[{','.join(files['test'])}]"],
                        folder)
    (folder / "cputime").write_text(f"{cpu:.1f} 0\n")
    return folder


def train_greybox(overrides: list[str], folder: Path) -> float:
    """``hysteresis-lab-train model=greybox <overrides>`` on one core into ``folder`` (its
    output in ``fit.log``); the process's CPU seconds."""
    folder.mkdir(parents=True, exist_ok=True)
    command = [str(Path(sys.executable).parent / "hysteresis-lab-train"), "model=greybox",
               *overrides, *QUIET, f"hydra.run.dir={folder}"]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    with (folder / "fit.log").open("w") as handle:
        proc = subprocess.Popen(command, cwd=REPO, env=env, stdout=handle,
                                stderr=subprocess.STDOUT)
        # this process's own resource use (fits run side by side share RUSAGE_CHILDREN)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise subprocess.CalledProcessError(proc.returncode, command)
    return usage.ru_utime + usage.ru_stime


def row(seed: int, settings: list[str], root: Path) -> dict[str, Any]:
    """A plant's structure and, per setting, its score, chosen structure and CPU seconds."""
    plant = json.loads((root / f"plant_{seed}" / "data" / "plant.json").read_text())
    sigma = plant["effects"]["noise"]["rms_um"]
    out: dict[str, Any] = {"seed": seed, "plant": plant["description"], "sigma": sigma}
    for setting in settings:
        folder = root / f"plant_{seed}" / setting
        metrics = json.loads((folder / "metrics.json").read_text())
        rmse = np.array([m["rmse_free_run"] for m in metrics["tests"].values()])
        model = json.loads((folder / "structure.json").read_text()) \
            if (folder / "structure.json").is_file() else _structure(folder)
        cpu = (folder / "cputime").read_text().split()
        out[setting] = {"ratio": float(rmse.mean()) / sigma, **model,
                        "cpu_s": float(cpu[0]) + float(cpu[1]),
                        **_chosen_cell(metrics)}
    return out


def _chosen_cell(metrics: dict[str, Any]) -> dict[str, Any]:
    """``model.hysteresis=auto``'s choice in a run's ``metrics.json``: the cell and how
    (``test``: the data test; ``val``: both fitted, the lower validation loss); empty for
    other runs."""
    chosen = (metrics.get("chosen_from_data") or {}).get("hysteresis")
    if chosen is None:
        return {}
    kept = metrics["chosen_from_data"].get("kept")
    cell = chosen.get("chosen") or (kept or "").removeprefix("hysteresis=")
    return {"cell": cell, "by": "test" if chosen["by"] == "data test" else "val",
            "test_ratio": chosen.get("bouc_wen_over_prandtl_ishlinskii")}


def _structure(folder: Path) -> dict[str, Any]:
    """The delay and modes the saved model holds."""
    from hysteresis_lab.models.io import load_model

    params = load_model(folder / "model.ckpt").physical_parameters()
    structure = {"delay": int(params["delay"]),
                 "modes_hz": np.round(params["mode"]["frequency_hz"], 0).tolist()}
    (folder / "structure.json").write_text(json.dumps(structure) + "\n")
    return structure


#: what a page's times are, unless it says otherwise
PROCESS_CPU = "CPU seconds of the whole `hysteresis-lab-train` process"


def page_header(title: str, command: str, clock: str = PROCESS_CPU) -> list[str]:
    """A page's title and provenance; ``clock``: what its times are."""
    from hysteresis_lab.evaluation.provenance import commit_stamp

    return [
        f"# {title}", "",
        f"Command: `{command}`; commit `{commit_stamp(REPO)}`; "
        f"{datetime.date.today().isoformat()}; shared 2-core CPU, one core per fit "
        f"(`OMP_NUM_THREADS=1`; {clock}). "
        "Fits found in the root are reused: the commit is the page's, a reused fit's may be "
        "older.", "",
    ]


def render_structure(rows: list[dict[str, Any]], command: str) -> str:
    """The page of ``--compare structure``."""
    lines = [
        *page_header("The grey-box's delay and modes from the data, on zoo plants", command),
        "Each plant fitted through `data=csv` with `model=greybox`: *fixed* is the former "
        "default structure (`model.delay=1 model.n_modes=1`), *auto* the default now "
        "(delay and modes chosen from the training data). Score: mean free-run RMSE over "
        "the twelve ±100 V test sines over the plant's noise σ.", "",
        "| seed | plant: delay, modes (Hz) | fixed | auto | auto chose: delay, modes (Hz) "
        "| CPU s fixed | CPU s auto |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        p = r["plant"]
        lines.append(
            f"| {r['seed']} | {p['delay_samples']}, {np.round(p['modes_hz'], 0).tolist()} "
            f"| {r['fixed']['ratio']:.3g} σ | {r['auto']['ratio']:.3g} σ "
            f"| {r['auto']['delay']}, {r['auto']['modes_hz']} "
            f"| {r['fixed']['cpu_s']:.0f} | {r['auto']['cpu_s']:.0f} |")
    ratios = {s: [r[s]["ratio"] for r in rows] for s in COMPARISONS["structure"]}
    lines += ["", f"Median: fixed {np.median(ratios['fixed']):.3g} σ, auto "
              f"{np.median(ratios['auto']):.3g} σ.", ""]
    return "\n".join(lines)


def _cell(plant: dict[str, Any]) -> str:
    """The plant's hysteresis cell in a few words."""
    if plant["cell"] == "prandtl_ishlinskii":
        return f"PI, {plant['plays']} plays (share {plant['pi_share']:.2f})"
    return f"BW n {plant['exponent']:.2f}" if "exponent" in plant else "BW"


def render_cell(rows: list[dict[str, Any]], command: str) -> str:
    """The page of ``--compare cell``."""
    lines = [
        *page_header("The grey-box's hysteresis cell on zoo plants: Bouc–Wen, "
                 "Prandtl–Ishlinskii or chosen from the data", command),
        "Each plant fitted through `data=csv` with `model=greybox` (its defaults: delay and "
        "modes from the data; the symmetric cell, `model.effects=[]`) and its Bouc–Wen cell "
        "(exponent 1), with `model.hysteresis=prandtl_ishlinskii` (play operators at fixed "
        "thresholds, weights learned), or with `model.hysteresis=auto` (the cell chosen from "
        "the training data: a least-squares test of both cells through the linear chain, "
        "*test*; where it leaves the choice open, both fitted and the lower validation "
        "free-run loss kept, *val*). Score: mean free-run RMSE over the twelve ±100 V test "
        "sines over the plant's noise σ. *test BW/PI*: the test's held-out misfit of "
        "Bouc–Wen over play operators (it decides where the lower is below 0.8 of the other "
        "and of the linear chain alone's).", "",
        "| seed | plant's cell | modes (Hz) | delay | Bouc–Wen | Prandtl–Ishlinskii | auto "
        "| auto chose | test BW/PI | CPU s BW | CPU s PI | CPU s auto |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        p, bw, pi, auto = r["plant"], r["bouc_wen"], r["prandtl_ishlinskii"], r["auto"]
        ratio = auto.get("test_ratio")
        lines.append(
            f"| {r['seed']} | {_cell(p)} | {np.round(p['modes_hz'], 0).tolist()} "
            f"| {p['delay_samples']} | {bw['ratio']:.3g} σ | {pi['ratio']:.3g} σ "
            f"| {auto['ratio']:.3g} σ | {_short(auto.get('cell', '?'))} ({auto.get('by', '?')}) "
            f"| {'' if ratio is None else f'{ratio:.2f}'} "
            f"| {bw['cpu_s']:.0f} | {pi['cpu_s']:.0f} | {auto['cpu_s']:.0f} |")
    lines.append("")
    for cell in ("prandtl_ishlinskii", "bouc_wen"):
        group = [r for r in rows if r["plant"]["cell"] == cell]
        if not group:
            continue
        bw = [r["bouc_wen"]["ratio"] for r in group]
        pi = [r["prandtl_ishlinskii"]["ratio"] for r in group]
        better = sum(b > p for b, p in zip(bw, pi, strict=True))
        lines.append(
            f"- On the {len(group)} plants with a {cell.replace('_', '–').title()} cell, play "
            f"operators fit better on {better}; median Bouc–Wen {np.median(bw):.3g} σ, "
            f"Prandtl–Ishlinskii {np.median(pi):.3g} σ.")
    best = [min(r["bouc_wen"]["ratio"], r["prandtl_ishlinskii"]["ratio"]) for r in rows]
    lines += [f"- The better cell per plant: median {np.median(best):.3g} σ over all "
              f"{len(rows)} (what a choice between the two by validation could reach at most)."]
    auto = [r["auto"]["ratio"] for r in rows]
    picked = [r for r in rows if r["auto"].get("cell") == _better_cell(r)]
    by_test = [r for r in rows if r["auto"].get("by") == "test"]
    alone = [r for r in rows if r["auto"].get("test_ratio") is not None]
    alone_cell = {r["seed"]: "bouc_wen" if r["auto"]["test_ratio"] < 1.0
                  else "prandtl_ishlinskii" for r in alone}
    cpu = {s: np.median([r[s]["cpu_s"] for r in rows]) for s in COMPARISONS["cell"]}
    lines += [
        f"- `auto`: median {np.median(auto):.3g} σ over all {len(rows)} (Bouc–Wen "
        f"{np.median([r['bouc_wen']['ratio'] for r in rows]):.3g} σ, Prandtl–Ishlinskii "
        f"{np.median([r['prandtl_ishlinskii']['ratio'] for r in rows]):.3g} σ); it chose the "
        f"better cell on {len(picked)} of {len(rows)} plants (missed: "
        f"{', '.join(_missed(r) for r in rows if r not in picked) or 'none'}); the data test "
        f"decided on {len(by_test)} ({sum(r in picked for r in by_test)} of them right), "
        f"validation on {len(rows) - len(by_test)}. The test alone (its lower misfit, "
        f"never both fitted) would have chosen the better cell on "
        f"{sum(alone_cell[r['seed']] == _better_cell(r) for r in alone)} of {len(alone)}, "
        f"median {np.median([r[alone_cell[r['seed']]]['ratio'] for r in alone]):.3g} σ, "
        "at one fit's CPU.",
        f"- CPU seconds per fit, median: Bouc–Wen {cpu['bouc_wen']:.0f}, Prandtl–Ishlinskii "
        f"{cpu['prandtl_ishlinskii']:.0f}, auto {cpu['auto']:.0f} (decided by the test "
        f"{_median_cpu(by_test)}, by validation "
        f"{_median_cpu([r for r in rows if r not in by_test])}).", ""]
    return "\n".join(lines)


def _short(cell: str) -> str:
    return {"bouc_wen": "BW", "prandtl_ishlinskii": "PI"}.get(cell, cell)


def _better_cell(r: dict[str, Any]) -> str:
    """The cell with the lower test error on plant row ``r``."""
    return ("bouc_wen" if r["bouc_wen"]["ratio"] <= r["prandtl_ishlinskii"]["ratio"]
            else "prandtl_ishlinskii")


def _missed(r: dict[str, Any]) -> str:
    """A plant where ``auto`` did not choose the better cell, and what that cost."""
    chosen, other = r["auto"]["ratio"], r[_better_cell(r)]["ratio"]
    return f"plant {r['seed']}, {chosen / other - 1:+.0%}"


def _median_cpu(rows: list[dict[str, Any]]) -> str:
    return f"{np.median([r['auto']['cpu_s'] for r in rows]):.0f}" if rows else "-"


#: per comparison, its page and how it is written
PAGES = {"structure": (RESULTS / "greybox_structure.md", render_structure),
         "cell": (RESULTS / "greybox_cell.md", render_cell)}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--compare", choices=sorted(COMPARISONS), default="structure")
    parser.add_argument("--seeds", default="0,1,4,6,7")
    parser.add_argument("--root", type=Path, default=None,
                        help="where the fits go (default outputs/greybox_<compare>)")
    parser.add_argument("--settings", default=None,
                        help="the settings to fit, comma-separated (the page needs both)")
    parser.add_argument("--render", action="store_true", help="only rewrite the page")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    settings = COMPARISONS[args.compare]
    root = args.root or Path(f"outputs/greybox_{args.compare}")
    seeds = [int(s) for s in args.seeds.split(",")]
    if not args.render:
        for seed in seeds:
            for setting in (args.settings or ",".join(settings)).split(","):
                folder = fit(seed, setting, settings[setting], root)
                log.info("plant %d: %s -> %s", seed, setting, folder)
    missing = [f"plant {seed} {setting}" for seed in seeds for setting in settings
               if not (root / f"plant_{seed}" / setting / "metrics.json").is_file()]
    if missing:
        raise SystemExit(f"page not written: no fit for {', '.join(missing)} in {root}. Fix: "
                         "run those settings (without --settings or --render) first.")
    rows = [row(seed, list(settings), root) for seed in seeds]
    page, render = PAGES[args.compare]
    compare = "" if args.compare == "structure" else f"--compare {args.compare} "
    page.write_text(render(rows, f"python benchmarks/greybox_structure.py {compare}--seeds "
                                 f"{args.seeds} --root <root>") + "\n")
    log.info("wrote %s", page)


if __name__ == "__main__":
    main()
