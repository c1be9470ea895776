"""The grey-box's delay and modes chosen from the data, on zoo plants: before and after.

    python benchmarks/greybox_structure.py --seeds 0,1,4,6,7 --root /tmp/gbs
    python benchmarks/greybox_structure.py --root /tmp/gbs --render     # only rewrite the page

Each zoo plant (`hysteresis_lab.sim.zoo.export_zoo_plant`) is fitted through ``data=csv`` with
``model=greybox`` twice: with the former fixed structure (``model.delay=1 model.n_modes=1``)
and with the defaults (``auto``: chosen from the training data). A fit done before (its
``metrics.json`` in ``<root>/plant_<seed>/<setting>``) is reused. The page,
``docs/results/greybox_structure.md``, gives per plant the free-run RMSE over the plant's
noise σ (mean of the twelve test sines), the structure the fit used and the process's CPU
seconds (one core: ``OMP_NUM_THREADS=1``).
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
OUT = REPO / "docs" / "results" / "greybox_structure.md"
#: the two settings compared: name -> model overrides
SETTINGS = {"fixed": ["model.delay=1", "model.n_modes=1"], "auto": []}
QUIET = ["logger=none", "trainer.enable_progress_bar=false"]

log = logging.getLogger("greybox_structure")


def fit(seed: int, setting: str, root: Path) -> Path:
    """Plant ``seed`` fitted with ``setting`` into its folder (reused when done)."""
    from hysteresis_lab.sim.zoo import export_zoo_plant

    folder = root / f"plant_{seed}" / setting
    if (folder / "metrics.json").is_file():
        return folder
    files = export_zoo_plant(seed, root / f"plant_{seed}" / "data")
    folder.mkdir(parents=True, exist_ok=True)
    command = [str(Path(sys.executable).parent / "hysteresis-lab-train"), "model=greybox",
               *SETTINGS[setting], "data=csv", f"data.train={files['train']}",
               f"data.val={files['val']}", f"data.test=[{','.join(files['test'])}]", *QUIET,
               f"hydra.run.dir={folder}"]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    with (folder / "fit.log").open("w") as handle:
        subprocess.run(command, cwd=REPO, env=env, stdout=handle, stderr=subprocess.STDOUT,
                       check=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    (folder / "cputime").write_text(f"{cpu:.1f} 0\n")
    return folder


def row(seed: int, root: Path) -> dict[str, Any]:
    """A plant's structure and, per setting, its score, chosen structure and CPU seconds."""
    plant = json.loads((root / f"plant_{seed}" / "data" / "plant.json").read_text())
    sigma = plant["effects"]["noise"]["rms_um"]
    out: dict[str, Any] = {"seed": seed, "plant": plant["description"], "sigma": sigma}
    for setting in SETTINGS:
        folder = root / f"plant_{seed}" / setting
        metrics = json.loads((folder / "metrics.json").read_text())
        rmse = np.array([m["rmse_free_run"] for m in metrics["tests"].values()])
        model = json.loads((folder / "structure.json").read_text()) \
            if (folder / "structure.json").is_file() else _structure(folder)
        cpu = (folder / "cputime").read_text().split()
        out[setting] = {"ratio": float(rmse.mean()) / sigma, **model,
                        "cpu_s": float(cpu[0]) + float(cpu[1])}
    return out


def _structure(folder: Path) -> dict[str, Any]:
    """The delay and modes the saved model holds."""
    from hysteresis_lab.models.io import load_model

    params = load_model(folder / "model.ckpt").physical_parameters()
    structure = {"delay": int(params["delay"]),
                 "modes_hz": np.round(params["mode"]["frequency_hz"], 0).tolist()}
    (folder / "structure.json").write_text(json.dumps(structure) + "\n")
    return structure


def render(rows: list[dict[str, Any]], command: str) -> str:
    """The page."""
    from hysteresis_lab.evaluation.provenance import commit_stamp

    stamp = commit_stamp(REPO)
    lines = [
        "# The grey-box's delay and modes from the data, on zoo plants", "",
        f"Command: `{command}`; commit `{stamp}`; "
        f"{datetime.date.today().isoformat()}; shared 2-core CPU, one core per fit "
        "(`OMP_NUM_THREADS=1`; CPU seconds of the whole `hysteresis-lab-train` process). "
        "Fits found in the root are reused: the commit is the page's, a reused fit's may be "
        "older.", "",
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
    ratios = {s: [r[s]["ratio"] for r in rows] for s in SETTINGS}
    lines += ["", f"Median: fixed {np.median(ratios['fixed']):.3g} σ, auto "
              f"{np.median(ratios['auto']):.3g} σ.", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0,1,4,6,7")
    parser.add_argument("--root", type=Path, default=Path("outputs/greybox_structure"))
    parser.add_argument("--settings", default=",".join(SETTINGS),
                        help="the settings to fit (the page needs both)")
    parser.add_argument("--render", action="store_true", help="only rewrite the page")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    seeds = [int(s) for s in args.seeds.split(",")]
    if not args.render:
        for seed in seeds:
            for setting in args.settings.split(","):
                log.info("plant %d: %s -> %s", seed, setting, fit(seed, setting, args.root))
    rows = [row(seed, args.root) for seed in seeds]
    OUT.write_text(render(rows, "python benchmarks/greybox_structure.py --seeds "
                          f"{args.seeds} --root <root>") + "\n")
    log.info("wrote %s", OUT)


if __name__ == "__main__":
    main()
