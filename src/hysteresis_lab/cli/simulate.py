"""``hysteresis-lab-simulate``: write a simulated positioner recording to CSV (t,u,y in s, V, µm).

Example::

    hysteresis-lab-simulate signal.kind=sine signal.frequency=1 effects.creep.enabled=false \
        output=sine_1Hz.csv
    hysteresis-lab-simulate zoo_seed=7 output=zoo_7.csv   # a random plant of the zoo
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from hysteresis_lab.cli._app import CONFIG_PATH, report_errors
from hysteresis_lab.errors import ConfigError

log = logging.getLogger(__name__)


@report_errors
def run(cfg: DictConfig) -> Path:
    """Generate the configured excitation, simulate it, write the CSV."""
    from hysteresis_lab.data.readers import write_csv
    from hysteresis_lab.signals import multisine, sine
    from hysteresis_lab.sim.positioner import simulate_recording

    sig = cfg.signal
    explicit = cfg.get("output")
    if explicit:  # checked before the simulation, which takes a while
        output_path(str(explicit))
    if sig.kind == "multisine":
        u = multisine(
            sig.n_samples,
            fs=cfg.fs,
            n_components=sig.n_components,
            f_max=sig.f_max,
            amplitude=sig.amplitude,
            seed=sig.seed,
        )
        name = "multisine"
    elif sig.kind == "sine":
        u = sine(sig.frequency, fs=cfg.fs, amplitude=sig.amplitude, n_periods=sig.n_periods)
        # sin starts at 0 V: the positioner starts at rest
        name = f"sine_{sig.frequency:g}Hz"
    else:
        raise ConfigError(f"unknown signal.kind '{sig.kind}'. Fix: signal.kind=multisine or sine.")
    effects = OmegaConf.to_container(cfg.effects, resolve=True)
    if cfg.get("zoo_seed") is not None:
        from hysteresis_lab.sim.zoo import draw_effects

        effects = draw_effects(int(cfg.zoo_seed))
        log.info("simulating plant %d of the zoo (effects.* overrides are not applied)",
                 cfg.zoo_seed)
    recording = simulate_recording(u, cfg.fs, effects, seed=cfg.seed, name=name)
    path = output_path(str(explicit or f"outputs/simulated/{name}.csv"))
    try:
        write_csv(recording, path)
    except OSError as exc:
        raise ConfigError(
            f"cannot write output={path}: {exc.strerror or exc}. "
            "Fix: output=<a writable .csv path>."
        ) from None
    log.info(
        "wrote %d samples (%s; effects: %s) to %s",
        recording.n_samples,
        name,
        ", ".join(recording.metadata["effects"]),
        path,
    )
    return path


def output_path(output: str) -> Path:
    """The CSV path ``output`` names, its folder created (and logged) where missing; a
    `ConfigError` when it is a folder or cannot be written."""
    path = Path(output)
    if path.is_dir() or output.endswith(("/", os.sep)):
        raise ConfigError(
            f"output={output} is a folder, not a file. Fix: output={path / 'recording.csv'}."
        )
    parent = path.parent
    blocking = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
    if blocking is not None:
        raise ConfigError(
            f"output={output}: {blocking} is a file, so no folder can be made there. "
            "Fix: output=<a .csv path in a writable folder>."
        )
    if not parent.is_dir():
        try:
            parent.mkdir(parents=True)
        except OSError as exc:
            raise ConfigError(
                f"output={output}: cannot create its folder {parent} ({exc.strerror or exc}). "
                "Fix: output=<a .csv path in a writable folder>."
            ) from None
        log.info("created the folder %s for output=%s", parent.resolve(), output)
    if not os.access(parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise ConfigError(
            f"output={output} is not writable. Fix: output=<a .csv path in a writable folder>."
        )
    return path


@hydra.main(config_path=CONFIG_PATH, config_name="simulate")
def _main(cfg: DictConfig) -> None:
    run(cfg)


def main() -> None:
    """Console-script entry point."""
    _main()


if __name__ == "__main__":
    main()
