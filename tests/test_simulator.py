"""The simulated piezo positioner: stroke, hysteresis loop, creep, resonances, noise, config."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from omegaconf import OmegaConf

import hysteresis_lab as hl
from hysteresis_lab.data.factory import build_splits
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.errors import ConfigError, DataError
from hysteresis_lab.physics.bouc_wen import bouc_wen_state
from hysteresis_lab.signals import multisine, sine
from hysteresis_lab.sim import Positioner, PositionerConfig, simulate_recording
from hysteresis_lab.sim.default_dataset import TEST_FREQUENCIES_HZ, make_default_dataset

FS = 20_000.0
CONF = Path(__file__).resolve().parents[1] / "src" / "hysteresis_lab" / "conf"
QUIET = {"noise": {"enabled": False}, "quantisation": {"enabled": False}}


def effects(**blocks: dict) -> dict:
    """Noise-free effects with the given block overrides."""
    return {**QUIET, **blocks}


def loop_of_third_period(u: np.ndarray, y: np.ndarray, fs: float, f: float):
    """Ascending and descending branch of the third period of a sine, on a common voltage grid."""
    period = fs / f
    a0, a1, a2 = int(1.75 * period), int(2.25 * period), int(2.75 * period)
    grid = np.linspace(-99.0, 99.0, 1001)
    ascending = np.interp(grid, u[a0 : a1 + 1], y[a0 : a1 + 1])
    descending = np.interp(grid, u[a1 : a2 + 1][::-1], y[a1 : a2 + 1][::-1])
    return ascending, descending, y[a0:a2].max() - y[a0:a2].min()


def peak_frequency(config: dict, f_max: float = 4000.0) -> tuple[np.ndarray, np.ndarray]:
    """|H(f)| of the positioner from a small periodic multisine (steady state, 1 Hz lines)."""
    n = 20_000
    u = multisine(n, fs=FS, n_components=int(f_max), f_max=f_max, amplitude=1.0, seed=1)
    y = Positioner(config).simulate(np.tile(u, 2), FS)[n:]
    freqs = np.fft.rfftfreq(n, 1.0 / FS)
    lines = np.arange(1, int(f_max) + 1)
    return freqs[lines], np.abs(np.fft.rfft(y)[lines] / np.fft.rfft(u)[lines])


# ---------------------------------------------------------------- hysteresis and stroke
def test_stroke_and_loop_width_at_full_amplitude():
    u = sine(1.0, fs=FS, amplitude=100.0, n_periods=3.0)
    y = Positioner(effects(creep={"enabled": False})).simulate(u, FS)
    ascending, descending, p2p = loop_of_third_period(u, y, FS, 1.0)
    assert p2p == pytest.approx(40.0, rel=0.10)
    width = np.max(np.abs(descending - ascending)) / p2p
    assert 0.10 <= width <= 0.15
    # piezo loops: the descending branch lies above the ascending one (h lags the input)
    assert np.all(descending[50:-50] > ascending[50:-50])


def test_linear_when_hysteresis_is_off():
    u = sine(1.0, fs=FS, amplitude=100.0, n_periods=3.0)
    y = Positioner(effects(creep={"enabled": False}, hysteresis={"enabled": False})).simulate(u, FS)
    ascending, descending, _ = loop_of_third_period(u, y, FS, 1.0)
    assert np.max(np.abs(descending - ascending)) < 0.1  # only the dynamics' phase lag


def test_bouc_wen_update_matches_fine_euler_integration():
    rng = np.random.default_rng(0)
    v = np.cumsum(rng.normal(0.0, 15.0, 60))  # large steps: exactness matters
    d, alpha, beta, gamma = 0.23, 0.32, 0.02, 0.006
    h_exact = bouc_wen_state(v, d, np.full(len(v), alpha), beta, gamma)
    h, v_prev, h_ref = 0.0, 0.0, []
    substeps = 2000
    for vk in v:
        dv = (vk - v_prev) / substeps
        for _ in range(substeps):
            h += alpha * d * dv - beta * abs(dv) * h - gamma * dv * abs(h)
        h_ref.append(h)
        v_prev = vk
    np.testing.assert_allclose(h_exact, h_ref, atol=2e-3)


def test_rate_dependence_widens_fast_loops():
    base = effects(creep={"enabled": False}, mode1={"enabled": False}, amplifier={"enabled": False})
    u = sine(100.0, fs=FS, amplitude=100.0, n_periods=3.0)
    widths = []
    for on in (False, True):
        y = Positioner({**base, "rate_dependence": {"enabled": on}}).simulate(u, FS)
        ascending, descending, p2p = loop_of_third_period(u, y, FS, 100.0)
        widths.append(np.max(descending - ascending) / p2p)
    assert widths[1] > 1.2 * widths[0]


def test_asymmetry_shifts_the_loop():
    u = sine(1.0, fs=FS, amplitude=100.0, n_periods=3.0)
    quiet = effects(creep={"enabled": False})
    last = slice(int(1.5 * FS), None)  # past the virgin curve
    y0 = Positioner(quiet).simulate(u, FS)[last]
    y1 = Positioner({**quiet, "asymmetry": {"enabled": True}}).simulate(u, FS)[last]
    assert y0.max() + y0.min() == pytest.approx(0.0, abs=0.05)  # symmetric loop
    # + 0.02 * 40 um at both extremes
    assert y1.max() + y1.min() == pytest.approx(1.6, abs=0.1)


def test_saturation_clips_the_amplifier_output():
    u = sine(1.0, fs=FS, amplitude=100.0, n_periods=2.0)
    base = effects(creep={"enabled": False}, amplifier={"enabled": False})
    clipped = Positioner({**base, "saturation": {"enabled": True, "limit_v": 50.0}}).simulate(u, FS)
    reference = Positioner(base).simulate(np.clip(u, -50.0, 50.0), FS)
    np.testing.assert_allclose(clipped, reference)
    full = Positioner(base).simulate(u, FS)
    assert np.ptp(clipped) < 0.6 * np.ptp(full)



def test_dead_zone_and_backlash_act_ahead_of_the_actuator():
    """A dead zone: the response to a command inside the band is nil, and beyond it the same
    as to the command less the band; backlash: a reversal moves nothing until the command
    has come back twice the play."""
    base = effects(creep={"enabled": False}, amplifier={"enabled": False},
                   hysteresis={"enabled": False}, mode1={"enabled": False},
                   input_delay={"enabled": False})
    dead = {**base, "dead_zone": {"enabled": True, "width_v": 10.0}}
    assert np.all(Positioner(dead).simulate(np.full(100, 9.0), FS) == 0.0)
    u = sine(1.0, fs=FS, amplitude=100.0)
    reference = Positioner(base).simulate(np.sign(u) * np.maximum(np.abs(u) - 10.0, 0.0), FS)
    np.testing.assert_allclose(Positioner(dead).simulate(u, FS), reference)
    play = {**base, "backlash": {"enabled": True, "width_v": 5.0}}
    ramp = np.concatenate([np.linspace(0.0, 50.0, 500), np.linspace(50.0, 30.0, 500)])
    y = Positioner(play).simulate(ramp, FS)
    gain = 0.23  # um/V with the hysteresis off
    assert y[499] == pytest.approx(gain * 45.0, abs=1e-3)  # follows 5 V behind
    back = 500 + np.flatnonzero(ramp[500:] <= 40.0)[0]  # 10 V down: the play taken up
    assert np.all(np.abs(y[500:back] - y[499]) < 1e-3) and y[-1] < y[499] - 1.0


# ---------------------------------------------------------------- creep and drift
def step_response(config: dict, seconds: float = 10.0) -> np.ndarray:
    u = np.full(int(seconds * FS), 50.0)
    return Positioner(config).simulate(u, FS)


def test_creep_keeps_rising_log_like():
    y = step_response(effects())
    at = {t: y[int(t * FS) - 1] for t in (1.0, np.sqrt(10.0), 10.0)}
    first, second = at[np.sqrt(10.0)] - at[1.0], at[10.0] - at[np.sqrt(10.0)]
    assert first > 0 and second > 0
    assert 0.5 < second / first < 2.0  # equal rise per half decade: logarithmic
    per_decade = (at[10.0] - at[1.0]) / at[1.0]
    assert 0.005 < per_decade < 0.03  # ~1.5 % per decade (PI: 1-2 %)


def test_no_creep_when_disabled():
    y = step_response(effects(creep={"enabled": False}))
    assert abs(y[int(10 * FS) - 1] - y[int(1 * FS) - 1]) < 1e-6


def test_drift_is_slow_and_input_independent():
    config = effects(creep={"enabled": False}, drift={"enabled": True})
    y = Positioner(config).simulate(np.zeros(int(30 * FS)), FS, seed=4)
    assert 0.05 < np.ptp(y) < 0.3
    assert np.max(np.abs(np.diff(y))) < 1e-4  # slow: no jumps between samples
    y_other = Positioner(config).simulate(np.full(int(30 * FS), 20.0), FS, seed=4)
    drift_other = y_other - y_other[int(FS)] - (y - y[int(FS)])
    assert np.max(np.abs(drift_other[int(FS) :])) < 1e-9


# ---------------------------------------------------------------- dynamics
def test_resonance_at_configured_mode1_frequency():
    for f_n in (900.0, 700.0):
        config = effects(
            hysteresis={"enabled": False}, creep={"enabled": False}, mode1={"frequency_hz": f_n}
        )
        freqs, gain = peak_frequency(config)
        assert freqs[np.argmax(gain)] == pytest.approx(f_n, rel=0.03)
        d = 0.23
        assert gain.max() / d == pytest.approx(1.0 / (2 * 0.03), rel=0.15)  # Q = 1/(2 zeta)
        assert gain[0] / d == pytest.approx(1.0, rel=0.01)  # unit DC gain


def test_second_mode_appears_when_enabled():
    base = effects(hysteresis={"enabled": False}, creep={"enabled": False})
    freqs, without = peak_frequency(base, f_max=4000.0)
    _, with_mode2 = peak_frequency({**base, "mode2": {"enabled": True}}, f_max=4000.0)
    band = (freqs > 2000) & (freqs < 4000)
    assert freqs[band][np.argmax(with_mode2[band])] == pytest.approx(2800.0, rel=0.03)
    near = np.argmin(np.abs(freqs - 2800.0))
    assert with_mode2[near] > 5 * without[near]


def test_input_and_output_delays_shift_the_response():
    """Started at rest, the positioner is time invariant: each delay shifts its response."""
    u = sine(10.0, fs=FS, n_periods=2.0)
    base = effects(creep={"enabled": False})
    assert PositionerConfig.from_dict(base).input_delay.samples == 1  # on by default
    y0 = Positioner(base).simulate(u, FS)
    y3 = Positioner({**base, "output_delay": {"enabled": True, "samples": 3}}).simulate(u, FS)
    np.testing.assert_allclose(y3[3:], y0[:-3])
    assert np.all(y3[:3] == 0.0)
    # the input delay: 1 sample by default, 5 here (4 more), off (1 fewer)
    y5 = Positioner({**base, "input_delay": {"samples": 5}}).simulate(u, FS)
    np.testing.assert_allclose(y5[4:], y0[:-4], atol=1e-12)
    assert np.all(y5[:6] == 0.0) and np.any(y0[:6] != 0.0)
    off = Positioner({**base, "input_delay": {"enabled": False}}).simulate(u, FS)
    np.testing.assert_allclose(off[:-1], y0[1:], atol=1e-12)
    both = Positioner({**base, "input_delay": {"samples": 5},
                       "output_delay": {"enabled": True, "samples": 3}}).simulate(u, FS)
    np.testing.assert_allclose(both[7:], y0[:-7], atol=1e-12)


# ---------------------------------------------------------------- noise
def test_sensor_noise_rms():
    config = {"creep": {"enabled": False}}
    y = Positioner(config).simulate(np.zeros(100_000), FS, seed=1)
    assert np.std(y) == pytest.approx(0.01, rel=0.2)
    assert np.allclose(y / 0.001, np.round(y / 0.001))  # 1 nm quantisation
    assert not np.array_equal(y, Positioner(config).simulate(np.zeros(100_000), FS, seed=2))
    np.testing.assert_array_equal(y, Positioner(config).simulate(np.zeros(100_000), FS, seed=1))


# ---------------------------------------------------------------- configuration
def test_unknown_block_names_the_valid_ones():
    with pytest.raises(ConfigError, match=r"unknown effect block 'creap'.*'creep'"):
        PositionerConfig.from_dict({"creap": {"enabled": False}})


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"creep": {"enabeld": False}},
         r"effect block 'creep' has no parameter\(s\) \['enabeld'\]\. Valid: \['enabled',"),
        ({"creep": False}, r"effect block 'creep' must be a mapping of parameters, got False"),
        ({"hysteresis": {"beta": 0.001, "gamma": 0.01}},
         r"hysteresis needs beta > \|gamma\| \(got beta=0.001, gamma=0.01\)"),
        ({"mode1": {"damping": 0.0}}, r"mode1 needs frequency_hz > 0 and damping > 0"),
        ({"quantisation": {"step_um": 0.0}}, r"quantisation.step_um=0.0 must be positive"),
        ({"input_delay": {"samples": -1}}, r"input_delay.samples must be >= 0"),
    ],
)
def test_invalid_configs_raise_config_error(values, message):
    with pytest.raises(ConfigError, match=message):
        PositionerConfig.from_dict(values)


def test_mode_above_nyquist_is_rejected():
    with pytest.raises(ConfigError, match="fs/2"):
        Positioner({"mode1": {"frequency_hz": 12_000.0}}).simulate(np.zeros(10), FS)


def test_bad_input_is_a_data_error():
    with pytest.raises(DataError, match="needs a non-empty 1-D input of finite values"):
        Positioner().simulate(np.array([0.0, np.nan]), FS)


def test_yaml_round_trips_and_omegaconf_is_accepted():
    values = yaml.safe_load((CONF / "sim" / "positioner.yaml").read_text())
    assert set(values) == {f for f in PositionerConfig.__dataclass_fields__}
    assert PositionerConfig.from_dict(values) == PositionerConfig()
    dict_config = OmegaConf.create(values)
    dict_config.mode1.frequency_hz = 700
    config = PositionerConfig.from_dict(dict_config)
    assert config.mode1.frequency_hz == 700
    assert config.creep.time_constants_s == [0.1, 1.0, 10.0, 100.0]
    assert PositionerConfig.from_dict(config.to_dict()) == config


def test_simulate_recording_records_the_effects():
    rec = simulate_recording(np.zeros(100), FS, {"creep": {"enabled": False}}, seed=3, name="zeros")
    assert rec.name == "zeros" and rec.u.shape == (100, 1) and rec.y.shape == (100, 1)
    assert rec.y_units == "um" and rec.u_units == "V"
    assert "creep" not in rec.metadata["effects"]
    assert "hysteresis" in rec.metadata["effects"]


# ---------------------------------------------------------------- default data set
def test_default_dataset_shapes_names_and_determinism():
    data = make_default_dataset()
    assert data.name == "default" and data.fs == FS
    assert len(data.train) == 1 and data.train[0].n_samples == 80_000
    assert np.max(np.abs(data.train[0].u)) == pytest.approx(100.0)
    names = [rec.name for rec in data.test]
    assert names[:2] == ["sine_0.1Hz", "sine_1Hz"] and names[-1] == "sine_500Hz"
    assert len(names) == len(TEST_FREQUENCIES_HZ) == 12
    for rec, f in zip(data.test, TEST_FREQUENCIES_HZ, strict=True):
        periods = 1 if f < 1 else 2
        assert rec.n_samples == round(periods * FS / f)
        assert rec.u[0, 0] == 0.0  # starts at rest
        assert abs(rec.y[0, 0]) < 0.1
        assert np.ptp(rec.u) == pytest.approx(200.0, rel=1e-2)
    again = make_default_dataset()
    np.testing.assert_array_equal(again.train[0].y, data.train[0].y)
    np.testing.assert_array_equal(again.test[3].y, data.test[3].y)
    other = make_default_dataset(seed=1)
    assert not np.array_equal(other.train[0].u, data.train[0].u)


def line_spectrum(u: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """A periodic input's spectrum on the multisine's lines (1 ... 500 Hz, every 1 Hz) and
    the largest amplitude off them (V)."""
    spectrum = np.fft.rfft(u[:, 0]) * 2 / len(u)
    freqs = np.fft.rfftfreq(len(u), 1.0 / fs)
    lines = (freqs > 0) & (freqs <= 500.0) & np.isclose(freqs, np.round(freqs))
    return spectrum[lines], np.abs(spectrum[~lines]).max()


def test_data_default_validates_on_a_second_realisation_of_the_multisine():
    """``data=default`` validates on a multisine of its own (README: "a second multisine
    recording"): the training multisine's lines, flat amplitude and ±100 V peak, other random
    phases, so not a repeat of the (periodic) training input."""
    cfg = hl.compose("data=default", "+data.splits.n_train=40000",
                     "+data.splits.test_frequencies=[500]", "+data.splits.max_test_samples=400")
    splits = build_splits(DataSpec.from_config(cfg.data))
    (train,), (val,) = splits.train, splits.val
    assert val.name == "multisine_validation" and val.n_samples == cfg.data.splits.val_samples
    assert not np.allclose(val.u[:, 0], train.u[: val.n_samples, 0])
    (train_lines, train_off), (val_lines, val_off) = (
        line_spectrum(rec.u, splits.fs) for rec in (train, val))
    assert len(val_lines) == len(train_lines) == 500 and max(train_off, val_off) < 1e-9
    for lines in (train_lines, val_lines):  # one amplitude on every line
        assert np.ptp(np.abs(lines)) < 1e-9 * np.abs(lines).max()
    assert np.abs(val_lines[0]) == pytest.approx(np.abs(train_lines[0]), rel=0.15)
    assert np.max(np.abs(val.u)) == pytest.approx(np.max(np.abs(train.u))) == 100.0
    # other phases: independent uniform phases differ by pi/2 on average, equal ones by 0
    phase_gap = np.abs(np.angle(val_lines * np.conj(train_lines)))
    assert phase_gap.mean() > 1.0


def test_default_dataset_accepts_effects_overrides():
    effects_cfg = OmegaConf.create(
        {"noise": {"enabled": False}, "quantisation": {"enabled": False}}
    )
    data = make_default_dataset(effects=effects_cfg, n_train=20_000)
    assert data.train[0].n_samples == 20_000
    assert "noise" not in data.train[0].metadata["effects"]
    with pytest.raises(ConfigError, match=r"unknown effect block 'creap'\. Valid: .*'creep'"):
        make_default_dataset(effects={"creap": {}})


def test_training_sines_join_the_training_set_never_the_test_frequencies():
    base = make_default_dataset(max_test_samples=400)
    richer = make_default_dataset(max_test_samples=400, train_sines=[3.0, 75.0])
    assert [r.name for r in richer.train] == ["multisine", "train_sine_3Hz", "train_sine_75Hz"]
    assert richer.train[2].n_samples == 2 * 20_000 // 75
    np.testing.assert_array_equal(richer.train[0].y, base.train[0].y)  # same multisine
    for a, b in zip(richer.test, base.test, strict=True):
        np.testing.assert_array_equal(a.y, b.y)  # same test data
    with pytest.raises(ConfigError, match="also test frequencies"):
        make_default_dataset(max_test_samples=400, train_sines=[10.0])


def test_training_sines_can_stay_below_the_test_amplitude():
    data = make_default_dataset(max_test_samples=400, train_sines=[3.0],
                                train_sine_amplitude=80.0)
    assert np.max(np.abs(data.train[1].u)) == pytest.approx(80.0, rel=1e-3)
    assert np.max(np.abs(data.test[3].u)) == pytest.approx(100.0, rel=1e-3)
    with pytest.raises(ConfigError, match="train_sine_amplitude"):
        make_default_dataset(max_test_samples=400, train_sines=[3.0], train_sine_amplitude=150.0)


def test_hold_recording_ends_the_test_set_and_shows_drift():
    base = make_default_dataset(max_test_samples=400)
    held = make_default_dataset(max_test_samples=400, test_hold_s=0.5)
    assert [r.name for r in held.test] == [r.name for r in base.test] + ["hold_0.5s"]
    for a, b in zip(held.test[:-1], base.test, strict=True):
        np.testing.assert_array_equal(a.y, b.y)  # the sines are unchanged
    assert held.test[-1].n_samples == 400  # truncated like the sines
    quiet = {"noise": {"enabled": False}, "quantisation": {"enabled": False}}
    short = {"n_train": 2_000, "test_frequencies": (500.0,), "test_hold_s": 0.5}
    still = make_default_dataset(effects=quiet, **short).test[-1]
    drifting = make_default_dataset(effects={**quiet, "drift": {"enabled": True}}, **short).test[-1]
    assert still.n_samples == int(0.5 * FS) and not np.any(still.u)
    assert np.ptp(still.y) < 1e-9  # held at rest, nothing the input drives moves
    assert np.ptp(drifting.y) > 0.001  # 4 nm/s plus the slow oscillation
    with pytest.raises(ConfigError, match="test_hold_s"):
        make_default_dataset(max_test_samples=400, test_hold_s=-1.0)
