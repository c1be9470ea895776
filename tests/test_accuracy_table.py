"""The accuracy table of docs/results (hysteresis_lab.evaluation.accuracy_table, written by
benchmarks/accuracy.py) from fabricated metrics.json files (no training)."""

from __future__ import annotations

import json

from hysteresis_lab.evaluation.accuracy_table import cell_from_metrics, write_results


def _metrics(path, tests, units):
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps({
        "model": "subnet", "units": {"u": "N", "y": units}, "train_seconds": 123.0,
        "tests": {name: {"rmse_free_run": free, "rmse_one_step": one}
                  for name, (free, one) in tests.items()},
    }))
    return path


def test_table_has_the_rows_and_references_and_merges(tmp_path):
    """Two runs written one after the other: the second keeps the first's rows, the
    references come from the loaders, FSM is scored per amplitude."""
    bw = _metrics(tmp_path / "subnet_bouc_wen" / "metrics.json",
                  {"bw_test_multisine": (0.0151, 0.0012), "bw_test_sinesweep": (0.0222, 0.0013)},
                  "mm")
    fsm_tests = {f"{amp}mV_test_r{r}_p{p}": (amp / 1000 + r / 1e4, amp / 1e4)
                 for amp in (100, 200, 300) for r in (1, 2, 3) for p in (1, 2)}
    fsm = _metrics(tmp_path / "subnet_fsm" / "metrics.json", fsm_tests, "um")
    results = tmp_path / "results"
    run = {"command": "python benchmarks/accuracy.py --data bouc_wen", "commit": "abc1234",
           "date": "2026-01-01", "host_note": "test"}
    stamp = {"commit": "abc1234", "date": "2026-01-01"}
    write_results([cell_from_metrics("subnet", "bouc_wen", bw, ["model.nx=8"], **stamp)], run,
                  results)
    write_results([cell_from_metrics("subnet", "fsm", fsm, [], **stamp)],
                  {**run, "command": "python benchmarks/accuracy.py --data fsm"}, results)
    md = (results / "accuracy.md").read_text()
    stored = json.loads((results / "accuracy.json").read_text())
    assert set(stored["cells"]) == {"bouc_wen/subnet", "fsm/subnet"}  # the merge kept both
    assert "--data fsm" in md and "abc1234" in md
    # Bouc-Wen: the multisine row beside PNLSS / dynoNet / NFIR (mm), the sweep without them
    assert "PNLSS [mm]" in md and "dynoNet [mm]" in md
    assert "| subnet | bw_test_multisine | 0.0151 | 0.0012 | 0.0187 | 0.0452 | 0.163 |" in md
    assert "|  | bw_test_sinesweep | 0.0222 | 0.0013 | – | – | – |" in md
    # FSM: per amplitude, mean over realisations and periods, beside NL-LFR and the BLA
    assert "NL-LFR [um]" in md and "BLA same amplitude [um]" in md
    assert "| subnet | 100 mV | 0.1002 | 0.01 | 0.0866 | 0.1142 |" in md
    assert "|  | 300 mV | 0.3002 | 0.03 | 0.1686 | 0.2277 |" in md
    assert "model=subnet data=bouc_wen model.nx=8" in md
    # a rerun of one cell replaces it, the other stays
    write_results([cell_from_metrics("subnet", "bouc_wen", bw, ["model.nx=16"], **stamp)], run,
                  results)
    md = (results / "accuracy.md").read_text()
    assert "model.nx=16" in md and "model.nx=8" not in md and "300 mV" in md


def test_the_augmented_row_names_its_model_and_baseline_and_is_explained(tmp_path):
    """A row that is no registered model (SUBNET on a baseline) shows the command it ran:
    its own ``model=`` override, the baseline's folder, and a note on what the row is."""
    tanks = _metrics(tmp_path / "augmented_cascaded_tanks" / "metrics.json",
                     {"tanks_test": (0.26, 0.05)}, "V")
    overrides = ["model=subnet", "model.baseline=<root>/linear_cascaded_tanks", "model.nx=3"]
    write_results([cell_from_metrics("augmented", "cascaded_tanks", tanks, overrides,
                                     commit="abc1234", date="2026-01-01")],
                  {"command": "x", "commit": "abc1234", "date": "2026-01-01"}, tmp_path / "r")
    md = (tmp_path / "r" / "accuracy.md").read_text()
    assert ("- augmented: `model=subnet data=cascaded_tanks "
            "model.baseline=<root>/linear_cascaded_tanks model.nx=3`") in md
    assert "model=augmented" not in md
    assert "*augmented*: SUBNET augmenting the data set's physical model" in md


def test_every_row_says_how_its_free_run_started(tmp_path):
    """metrics.json's ``initial_state`` reaches the table: in the free-run heading where the
    section's rows share it, beside each model where they differ."""
    tests = {"tanks_test": (0.26, 0.05)}
    rest = _metrics(tmp_path / "rest" / "metrics.json", tests, "V")
    estimated = _metrics(tmp_path / "estimated" / "metrics.json", tests, "V")
    estimated.write_text(json.dumps({**json.loads(estimated.read_text()),
                                     "initial_state": "estimate"}))
    stamp = {"commit": "abc1234", "date": "2026-01-01"}
    run = {"command": "x", **stamp}
    write_results([cell_from_metrics("linear", "cascaded_tanks", rest, [], **stamp)], run,
                  tmp_path / "r")
    md = (tmp_path / "r" / "accuracy.md").read_text()
    assert "free run from rest [V]" in md
    write_results([cell_from_metrics("greybox", "cascaded_tanks", estimated, [], **stamp)], run,
                  tmp_path / "r")
    md = (tmp_path / "r" / "accuracy.md").read_text()
    assert "| free run [V] |" in md
    assert "| greybox (from an estimated start) | tanks_test |" in md
    assert "| linear (from rest) | tanks_test |" in md
