"""The GPU path, checked end to end: each architecture trains through the real CLI on a GPU.

    python benchmarks/gpu_check.py                      # all checks, page to docs/results
    python benchmarks/gpu_check.py --out /tmp/gpu.md --checks ffnn linear_emps

Every check runs ``hysteresis-lab-train`` (or ``hysteresis-lab-loop``) with
``trainer.accelerator=gpu``, so a run that cannot use the GPU fails instead of falling back
to the CPU, and records whether Lightning reported the GPU used, the wall time of the whole
command and the free-run RMSE it scored (short trainings: these check the path, they are not
the accuracy table's figures). The page (``docs/results/gpu_check.md``) also holds the
training and free-run speed of `bench_models.py` on the GPU and on the same machine's CPU.
Run it on a machine with a CUDA GPU; it needs the project installed there.
"""

from __future__ import annotations

import argparse
import datetime
import json
import logging
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import torch

from hysteresis_lab.evaluation.provenance import commit_stamp

log = logging.getLogger("gpu_check")

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "results" / "gpu_check.md"
#: short test sines keep the default data's free-run scoring quick (the 0.1 Hz sine alone is
#: 200,000 sequential steps)
SHORT_TESTS = ["+data.splits.test_frequencies=[10,100]", "+data.splits.max_test_samples=4000"]
#: check -> (console app, Hydra overrides)
CHECKS: dict[str, tuple[str, list[str]]] = {
    "ffnn": ("hysteresis-lab-train", ["model=ffnn", "trainer.max_epochs=5", *SHORT_TESTS]),
    "lstm": ("hysteresis-lab-train", ["model=lstm", "trainer.max_epochs=3", *SHORT_TESTS]),
    "cnn": ("hysteresis-lab-train", ["model=cnn", "trainer.max_epochs=3", *SHORT_TESTS]),
    "subnet_emps": ("hysteresis-lab-train", ["model=subnet", "data=emps", "training.horizon=300",
                                             "training.lr=1e-3", "data.batch_size=16",
                                             "trainer.max_epochs=10"]),
    "linear_emps": ("hysteresis-lab-train", ["model=linear", "data=emps",
                                             "model.integrator=true"]),
    "greybox_p885": ("hysteresis-lab-train", ["model=greybox", "data=p885"]),
    # resume off: on a machine that ran the check before, the loop would reuse its finished fits
    "loop_tanks": ("hysteresis-lab-loop", ["data=cascaded_tanks", "loop.max_rounds=1",
                                           "loop.resume=false"]),
}
QUIET = ["logger=none", "trainer.enable_progress_bar=false"]
#: what gpu_check asks of bench_models.py, and the header of the table it logs
BENCH_ARGS = ["--epochs", "2", "--models", "ffnn", "lstm", "cnn", "subnet"]
BENCH_HEADER = ("| model | s/epoch | fit, 100 epochs [s] | one-step [µs/sample] | "
                "free-run [steps/s] | free-run [recording-samples/s] | one recording [steps/s] |")
#: the studies with a GPU path (the SVM is fitted by scikit-learn on the CPU)
GPU_STUDY = ["ffnn", "lstm", "cnn"]


def run_check(name: str, root: Path, timeout_s: float) -> dict:
    """One check's command, exit status, GPU use, wall time and scored free-run RMSE."""
    app, overrides = CHECKS[name]
    folder = root / name
    shutil.rmtree(folder, ignore_errors=True)  # a fresh run, not one resumed in an old folder
    command = [app, *overrides, "trainer.accelerator=gpu", *QUIET, f"hydra.run.dir={folder}"]
    start = time.perf_counter()
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s)
        status, output = done.returncode, done.stdout + done.stderr
    except subprocess.TimeoutExpired as exc:  # its output comes as bytes, text=True or not
        status, output = "timeout", _text(exc.stdout) + _text(exc.stderr)
    seconds = time.perf_counter() - start
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "gpu_check.log").write_text(output)
    return {"command": " ".join([app, *overrides, "trainer.accelerator=gpu"]), "status": status,
            "gpu_used": re.search(r"GPU available: True.*used: True", output) is not None,
            "seconds": seconds, "rmse": _free_run_rmse(folder, app),
            "error": [] if status == 0 else output.strip().splitlines()[-1:]}


def _text(value: bytes | str | None) -> str:
    return value.decode(errors="replace") if isinstance(value, bytes) else value or ""


def _free_run_rmse(folder: Path, app: str) -> str:
    """The mean free-run RMSE the run scored, with its unit ('' when it wrote none)."""
    if app == "hysteresis-lab-loop":
        report = folder / "loop_report.json"
        if not report.is_file():
            return ""
        data = json.loads(report.read_text())
        rounds = data["rounds"]
        result = data["result"] if data["result"] is not None else 0
        return (f"{rounds[0]['mean_rmse_free_run']:.4g} -> "
                f"{rounds[result]['mean_rmse_free_run']:.4g} {data['units']['y']}")
    metrics = folder / "metrics.json"
    if not metrics.is_file():
        return ""
    data = json.loads(metrics.read_text())
    return f"{data['mean']['rmse_free_run']:.4g} {data['units']['y']}"


def bench(device: str, timeout_s: float, max_test_samples: int | None) -> str:
    """`bench_models.py`'s table on ``device``: the rows it measured, and why it stopped where
    it ran past ``timeout_s``."""
    command = [sys.executable, str(REPO / "benchmarks" / "bench_models.py"), "--device", device,
               *BENCH_ARGS]
    if max_test_samples:
        command += ["--max-test-samples", str(max_test_samples)]
    note = ""
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s)
        output = done.stdout + done.stderr
    except subprocess.TimeoutExpired as exc:  # keep the rows measured before the limit
        output = _text(exc.stdout) + _text(exc.stderr)
        note = f"(`bench_models.py --device {device}` ran past {timeout_s:.0f} s here)"
    lines = output.strip().splitlines()
    head = [line for line in lines if line.startswith("device ")]
    # each row is logged once as it is measured, and again in the closing table
    rows = list(dict.fromkeys(line for line in lines if line.startswith("| ")
                              and not line.startswith("| model |")))
    if not rows:
        return "\n".join(lines[-3:] + [note])
    table = [*head, BENCH_HEADER, "|---|---|---|---|---|---|---|", *rows]
    return "\n".join(table + ([note] if note else []))


def study(n_trials: int, max_epochs: int | None, stamp: str, root: Path,
          timeout_s: float) -> str:
    """`pareto_study.py` on the GPU (the NARX networks; the SVM has no GPU path): its table of
    wall times and its total line, or why there is none."""
    out = root / "pareto_gpu.md"
    command = [sys.executable, str(REPO / "benchmarks" / "pareto_study.py"), "--archs", *GPU_STUDY,
               "--n-trials", str(n_trials), "--results", str(root / "pareto"), "--out", str(out),
               "--commit", stamp]
    if max_epochs is not None:
        command += ["--max-epochs", str(max_epochs)]
    command.append("trainer.accelerator=gpu")
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return f"(the study ran past {timeout_s:.0f} s)"
    if done.returncode != 0 or not out.is_file():
        return "\n".join((done.stdout + done.stderr).strip().splitlines()[-3:])
    page = out.read_text().splitlines()
    # only the wall-time table: the fronts below it are the tuning result, not the speed
    end = next((i for i, line in enumerate(page) if line.startswith("Total:")), len(page))
    studies = [line for line in page[:end] if line.startswith("- studies:")]
    table = [line for line in page[:end] if line.startswith(("| ", "|---"))]
    return "\n".join([*studies, "", *table, "", *page[end:end + 1]])


def render(rows: dict[str, dict], benches: dict[str, str], stamp: str, argv: str,
           study_table: str = "", bench_extra: str = "") -> str:
    name = torch.cuda.get_device_name() if torch.cuda.is_available() else "no CUDA device"
    lines = [
        "# The GPU path",
        "",
        f"Written by `python benchmarks/gpu_check.py{argv}` at commit `{stamp}` on "
        f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC, on {name} (torch "
        f"{torch.__version__}, {os.cpu_count()} CPU cores). Each check trains through the "
        "console app with `trainer.accelerator=gpu` (no fallback to the CPU). Short trainings: "
        "they check the path; the accuracy table has the figures.",
        "",
        "| check | exit | GPU used | wall time | free-run RMSE (mean over tests) | command |",
        "|---|---|---|---|---|---|",
    ]
    for check, row in rows.items():
        lines.append(f"| {check} | {row['status']} | {'yes' if row['gpu_used'] else 'no'} | "
                     f"{row['seconds']:.0f} s | {row['rmse']} | `{row['command']}` |")
    errors = [f"- {check}: {' '.join(row['error'])}" for check, row in rows.items()
              if row["error"]]
    if errors:
        lines += ["", "Failures (the last line of their output):", "", *errors]
    for device, table in benches.items():
        lines += ["", f"Speed on the {device.upper()} (`python benchmarks/bench_models.py "
                  f"--device {device} {' '.join(BENCH_ARGS)}{bench_extra}`; untrained "
                  "weights):", "", table]
    if study_table:
        lines += ["", "Tuning study on the GPU (`benchmarks/pareto_study.py --archs "
                  f"{' '.join(GPU_STUDY)} ... trainer.accelerator=gpu`, one trial at a time):",
                  "", study_table]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checks", nargs="+", default=list(CHECKS), choices=list(CHECKS))
    parser.add_argument("--root", type=Path, default=REPO / "outputs" / "gpu_check")
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds per check")
    parser.add_argument("--bench", nargs="*", default=["cuda", "cpu"], choices=["cuda", "cpu"])
    parser.add_argument("--bench-samples", type=int, default=None, help="cut the test sines "
                        "of the speed tables to this many samples (bench_models.py "
                        "--max-test-samples)")
    parser.add_argument("--study-trials", type=int, default=0, help="trials of each GPU "
                        "tuning study (0: no study)")
    parser.add_argument("--study-epochs", type=int, default=None,
                        help="trainer.max_epochs of the study's trials (default: the config's)")
    parser.add_argument("--commit", default=None, help="the commit measured, where this copy "
                        "of the project has no git history (a device machine's copy)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if not torch.cuda.is_available():
        raise SystemExit("no CUDA device here: run this on a machine with a GPU")
    stamp = args.commit or commit_stamp(REPO)
    argv = "".join(f" {a}" for a in sys.argv[1:])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    rows: dict[str, dict] = {}
    benches: dict[str, str] = {}
    study_table = ""
    extra = f" --max-test-samples {args.bench_samples}" if args.bench_samples else ""
    # the page is rewritten after each step: a run cut short keeps what it measured
    for device in args.bench:
        benches[device] = bench(device, 3 * args.timeout, args.bench_samples)
        args.out.write_text(render(rows, benches, stamp, argv, study_table, extra))
    if args.study_trials:
        study_table = study(args.study_trials, args.study_epochs, stamp, args.root,
                            6 * args.timeout)
        args.out.write_text(render(rows, benches, stamp, argv, study_table, extra))
    for check in args.checks:
        rows[check] = run_check(check, args.root, args.timeout)
        log.info("%s: exit %s, GPU used %s, %.0f s, %s", check, rows[check]["status"],
                 rows[check]["gpu_used"], rows[check]["seconds"], rows[check]["rmse"])
        args.out.write_text(render(rows, benches, stamp, argv, study_table, extra))
    log.info("wrote %s", args.out)


if __name__ == "__main__":
    main()
