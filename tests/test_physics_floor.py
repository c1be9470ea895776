"""The physics floor sits below the simulator, the blocks and the effects: it imports none
of them, and the blocks and effects take their math from it, not from the simulator."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import torch

from hysteresis_lab.physics.bouc_wen import BoucWenStates, bouc_wen_advance, bouc_wen_state
from hysteresis_lab.physics.play import play, play_operators

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "hysteresis_lab"


def imported_modules(folder: str) -> set[str]:
    """Every ``hysteresis_lab`` module the files of ``folder`` import (at any depth)."""
    found = set()
    for path in (PACKAGE / folder).glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                found.add(node.module)
            elif isinstance(node, ast.Import):
                found.update(alias.name for alias in node.names)
    return {name for name in found if name.startswith("hysteresis_lab")}


def test_the_floor_imports_nothing_above_it():
    above = ("hysteresis_lab.sim", "hysteresis_lab.blocks", "hysteresis_lab.effects",
             "hysteresis_lab.models")
    assert not [m for m in imported_modules("physics") if m.startswith(above)]


def test_blocks_and_effects_do_not_import_the_simulator_at_module_level():
    for folder in ("blocks", "effects"):
        for path in (PACKAGE / folder).glob("*.py"):
            tree = ast.parse(path.read_text())
            top = [n.module for n in tree.body if isinstance(n, ast.ImportFrom) and n.module]
            assert not [m for m in top if m.startswith("hysteresis_lab.sim")], path.name


def test_one_bouc_wen_update_for_the_simulator_and_the_torch_faces():
    """The simulator's state, the batched torch function and the one-sample torch step run
    the same update to the last bit of float64."""
    rng = np.random.default_rng(0)
    v = np.cumsum(rng.normal(size=400))
    alpha, d, beta, gamma = 0.3, 0.9, 0.05, 0.01
    reference = bouc_wen_state(v, d, np.full(len(v), alpha), beta, gamma)
    t = torch.as_tensor(v)[None]
    one = torch.ones(1, dtype=torch.float64)
    states = BoucWenStates.apply(t, torch.zeros(1, dtype=torch.float64),
                                 torch.zeros(1, 1, dtype=torch.float64), one * alpha * d,
                                 one * (beta - gamma), one * (beta + gamma))
    np.testing.assert_array_equal(states[0, :, 0].numpy(), reference)
    h, previous, stepped = torch.zeros(1), 0.0, []
    for value in v:
        h = bouc_wen_advance(h, torch.tensor([value - previous], dtype=torch.float64),
                             one * alpha * d, one * (beta - gamma), one * (beta + gamma))
        stepped.append(float(h[0]))
        previous = value
    np.testing.assert_allclose(stepped, reference, rtol=1e-12, atol=1e-12)


def test_one_play_operator_in_numpy_and_torch():
    v = np.sin(np.linspace(0.0, 12.0, 300)) * np.linspace(0.2, 1.0, 300)
    thresholds = np.array([0.05, 0.3])
    expected = play_operators(v, thresholds)
    got = play(torch.as_tensor(v)[None], torch.as_tensor(thresholds))[0].numpy()
    np.testing.assert_array_equal(got, expected)
