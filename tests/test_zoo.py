"""The zoo of positioners: reproducible from its seed, inside its documented prior (the
default plant too), finite and stable on the study's multisine; the simulator pieces it needs
(a Bouc–Wen exponent, a Prandtl–Ishlinskii cell, a third mode) and its CSV export."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from hysteresis_lab.data.user_files import load_user_files
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.physics.bouc_wen import bouc_wen_state
from hysteresis_lab.signals import multisine, sine
from hysteresis_lab.sim import Positioner, PositionerConfig
from hysteresis_lab.sim.reference_chain import chain_from_positioner
from hysteresis_lab.sim.zoo import (
    OFF_BLOCKS,
    ZooPrior,
    draw_effects,
    draw_plant,
    export_zoo_plant,
    outside_prior,
)

FS = 20_000.0
SEEDS = range(40)
QUIET = {"noise": {"enabled": False}, "quantisation": {"enabled": False},
         "creep": {"enabled": False}}


@pytest.fixture(scope="module")
def study_multisine() -> np.ndarray:
    """The study's excitation (500 lines to 500 Hz, ±100 V), one second of it."""
    return multisine(20_000, fs=FS, amplitude=100.0, seed=3)


def test_same_seed_gives_the_same_plant_and_output(study_multisine):
    u = study_multisine[:4000]
    assert draw_effects(7) == draw_effects(7)
    assert draw_plant(7) == draw_plant(7)
    y1 = Positioner(draw_plant(7)).simulate(u, FS, seed=1)
    y2 = Positioner(draw_plant(7)).simulate(u, FS, seed=1)
    np.testing.assert_array_equal(y1, y2)
    plants = [draw_effects(seed) for seed in range(10)]
    assert all(a != b for i, a in enumerate(plants) for b in plants[i + 1:])
    y3 = Positioner(draw_plant(8)).simulate(u, FS, seed=1)
    assert not np.allclose(y1, y3)


def test_every_drawn_parameter_lies_inside_the_prior():
    prior = ZooPrior()
    for seed in SEEDS:
        plant = draw_plant(seed)
        assert outside_prior(plant, prior) == [], seed
        # the ranges read directly, apart from outside_prior's reading of them
        h = plant.hysteresis
        assert prior.gain_um_per_v[0] <= h.d_um_per_v <= prior.gain_um_per_v[1]
        modes = [m for m in (plant.mode1, plant.mode2, plant.mode3) if m.enabled]
        assert plant.mode1.enabled and 1 <= len(modes) <= 3
        assert all(300.0 <= m.frequency_hz <= 5000.0 and 0.005 <= m.damping <= 0.1
                   for m in modes)
        assert 1000.0 <= plant.amplifier.cutoff_hz <= 20_000.0
        assert 0 <= plant.input_delay.samples <= 5
        assert 0.003 <= plant.noise.rms_um <= 0.05
        assert not any(getattr(plant, key).enabled for key in OFF_BLOCKS)
        if h.cell == "bouc_wen":
            assert h.beta > abs(h.gamma) and 1.0 <= h.exponent <= 3.0


def test_the_prior_is_covered_whole():
    """Both cells, both signs of the rates' ratio, exponents above one, one to three modes,
    symmetric and asymmetric loops, creep or none, every delay: the draws span the prior."""
    plants = [draw_plant(seed) for seed in SEEDS]
    cells = {p.hysteresis.cell for p in plants}
    assert cells == {"bouc_wen", "prandtl_ishlinskii"}
    bw = [p.hysteresis for p in plants if p.hysteresis.cell == "bouc_wen"]
    assert min(h.gamma for h in bw) < 0 < max(h.gamma for h in bw)
    assert max(h.exponent for h in bw) > 2.0
    pi = [p.hysteresis for p in plants if p.hysteresis.cell == "prandtl_ishlinskii"]
    gaps = np.concatenate([np.diff(h.thresholds_v) for h in pi if len(h.thresholds_v) > 2])
    assert gaps.max() > 3 * gaps.min()  # uneven thresholds
    counts = {sum(m.enabled for m in (p.mode1, p.mode2, p.mode3)) for p in plants}
    assert counts == {1, 2, 3}
    assert {p.asymmetry.enabled for p in plants} == {True, False}
    assert {p.creep.enabled for p in plants} == {True, False}
    assert {p.input_delay.samples for p in plants} == set(range(6))


def test_the_default_plant_is_one_point_of_the_prior():
    default = PositionerConfig()
    assert outside_prior(default) == []
    # the check can fail: a plant off the prior in one parameter is named
    louder = dataclasses.replace(default.noise, rms_um=0.2)
    off = PositionerConfig.from_dict({"noise": dataclasses.asdict(louder)})
    assert outside_prior(off) == ["noise (um)=0.2 outside [0.003, 0.05]"]
    clipped = PositionerConfig.from_dict({"saturation": {"enabled": True}})
    assert outside_prior(clipped) == ["saturation is on (no zoo plant has it)"]


def test_drawn_plants_are_finite_and_stable_on_the_study_multisine(study_multisine):
    # 0.8 s at rest after the multisine: seven decay times of the prior's slowest mode
    # (300 Hz, damping 0.005)
    tail = 16_000
    u = np.concatenate([study_multisine, np.zeros(tail)])
    for seed in range(12):
        effects = {**draw_effects(seed), **QUIET}
        y = Positioner(effects).simulate(u, FS)
        d = effects["hysteresis"]["d_um_per_v"]
        assert np.all(np.isfinite(y)), seed
        # bounded: below the stroke times the sharpest resonance's amplification
        assert np.max(np.abs(y)) < 100.0 * d * 100.0, seed
        # stable: at rest the output settles on the hysteresis' remanence
        assert np.ptp(y[-500:]) < 1e-3 * np.ptp(y), seed


def test_bouc_wen_exponent_one_matches_the_exact_update_and_two_saturates_lower():
    v = sine(3.0, fs=FS, amplitude=100.0, n_periods=2.0)
    alpha = np.full(len(v), 0.32)
    exact = bouc_wen_state(v, 0.23, alpha, 0.02, 0.006)
    # an exponent next to one takes the numerical integration, and lands on the exact update
    integrated = bouc_wen_state(v, 0.23, alpha, 0.02, 0.006, 1.0 + 1e-9)
    np.testing.assert_allclose(integrated, exact, atol=1e-5)
    # n = 2: the state saturates at (alpha d / (beta + gamma))^(1/2)
    h2 = bouc_wen_state(v, 0.23, alpha, 0.02, 0.006, 2.0)
    assert np.max(np.abs(h2)) == pytest.approx((0.32 * 0.23 / 0.026) ** 0.5, rel=0.01)


def test_the_simulator_runs_the_cell_with_its_exponent():
    v = sine(3.0, fs=FS, amplitude=100.0, n_periods=2.0)
    bare = {**QUIET, "mode1": {"enabled": False}, "amplifier": {"enabled": False},
            "input_delay": {"samples": 0}}
    y = Positioner({**bare, "hysteresis": {"exponent": 2.0}}).simulate(v, FS)
    h2 = bouc_wen_state(v, 0.23, np.full(len(v), 0.32), 0.02, 0.006, 2.0)
    np.testing.assert_allclose(y, 0.23 * v - h2, atol=1e-9)


def test_three_modes_in_the_reference_chain_reproduce_the_simulator():
    cfg = {**QUIET, "mode2": {"enabled": True}, "mode3": {"enabled": True, "weight": 0.1}}
    u = multisine(4000, fs=FS, amplitude=100.0, seed=5)
    y_sim = Positioner(cfg).simulate(u, FS)
    chain = chain_from_positioner(cfg, FS, 100.0, 20.0).double()
    y = chain(torch.tensor(u[None] / 100.0))[0].detach().numpy() * 20.0
    assert np.max(np.abs(y - y_sim)) / np.max(np.abs(y_sim)) < 1e-6


def test_prandtl_ishlinskii_cell_widens_the_loop_by_its_plays():
    """One play of threshold r and weight w opens the major loop by ``2 d w r``."""
    u = sine(1.0, fs=FS, amplitude=100.0, n_periods=2.0)
    effects = {**QUIET, "mode1": {"enabled": False}, "amplifier": {"enabled": False},
               "input_delay": {"samples": 0},
               "hysteresis": {"cell": "prandtl_ishlinskii", "d_um_per_v": 0.2,
                              "thresholds_v": [20], "weights": [0.3]}}
    y = Positioner(effects).simulate(u, FS)
    second = slice(int(FS), 2 * int(FS))
    crossings = np.where(np.diff(np.sign(u[second])) != 0)[0]
    widths = np.abs(np.diff(y[second][crossings]))
    assert widths.max() == pytest.approx(2 * 0.2 * 0.3 * 20, rel=0.02)
    for bad in ({"weights": [1.2]}, {"thresholds_v": [20, 40]}, {"thresholds_v": [-5]}):
        with pytest.raises(ConfigError):
            PositionerConfig.from_dict({"hysteresis": {**effects["hysteresis"], **bad}})
    with pytest.raises(ConfigError, match="exponent"):
        PositionerConfig.from_dict({"hysteresis": {"exponent": 0.5}})


def test_third_mode_adds_its_resonance():
    u = sine(4500.0, fs=FS, amplitude=1.0, n_periods=400.0)
    base = {**QUIET, "mode1": {"frequency_hz": 900.0}}
    without = Positioner(base).simulate(u, FS)
    with_mode3 = Positioner({**base, "mode3": {"enabled": True, "weight": 0.05}}).simulate(u, FS)
    assert np.std(with_mode3[-4000:]) > 3 * np.std(without[-4000:])


def test_exported_plant_reads_back_through_the_csv_path(tmp_path):
    paths = export_zoo_plant(3, tmp_path, max_test_samples=4000)
    splits = load_user_files(paths["train"], test=paths["test"], val=paths["val"])
    assert len(splits.train) == 1 and len(splits.val) == 1 and len(splits.test) == 12
    assert splits.train[0].n_samples == 80_000 and splits.val[0].n_samples == 20_000
    y = Positioner(draw_plant(3)).simulate(splits.train[0].u[:, 0], FS, seed=0)
    assert np.std(splits.train[0].y[:, 0]) == pytest.approx(np.std(y), rel=0.05)


def test_simulate_app_runs_a_zoo_plant(tmp_path):
    from hysteresis_lab.api import compose
    from hysteresis_lab.cli.simulate import run

    out = tmp_path / "zoo_3.csv"
    cfg = compose("zoo_seed=3", "signal.n_samples=2000", f"output={out}", config="simulate")
    run(cfg)
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    expected = Positioner(draw_plant(3)).simulate(data[:, 1], FS, seed=0)
    np.testing.assert_allclose(data[:, 2], expected, atol=1e-6)
