"""How hard the test recordings drive each effect's operators against the identification data.

    python experiments/operator_excitation.py            # the default data and every case
    python experiments/operator_excitation.py --effects hysteresis saturation

The ratio the loop reports with each effect it adds (`hysteresis_lab.loop.diagnosis.excitation`),
here for every catalogue effect on the packaged data: the default data (the study's multisine
against its twelve sines) and the data of each undeclared-effect case of
``experiments/undeclared_effects.py``. Data only: nothing is trained; a few seconds.
"""

from __future__ import annotations

import argparse
import logging

from undeclared_effects import CASE_DATA, CASES  # the script beside

from hysteresis_lab.api import compose
from hysteresis_lab.data.factory import build_splits
from hysteresis_lab.effects.registry import available_effects, get_effect
from hysteresis_lab.loop.diagnosis.excitation import operator_excitation
from hysteresis_lab.models.augment import feature_context

log = logging.getLogger("operator_excitation")


def data_overrides() -> dict[str, list[str]]:
    """Each data set: the packaged default, then each undeclared-effect case's."""
    cases = {
        name: [
            f"data.effects.{block}.enabled=true",
            *CASE_DATA.get(name, []),
        ]
        for name, (block, _, _) in CASES.items()
    }
    return {"default": [], **cases}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    predictable = [e for e in available_effects() if get_effect(e).predictable]
    parser.add_argument("--effects", nargs="+", default=predictable, choices=predictable)
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for name, overrides in data_overrides().items():
        splits = build_splits(compose(*overrides, config="loop").data)
        context = feature_context(splits.train)
        for effect in args.effects:
            excitation = operator_excitation(
                effect, [*splits.train, *splits.val], splits.test, context
            )
            ratios = ", ".join(
                "never" if r is None else f"{r:.2g}" for r in excitation.ratios.values()
            )
            log.info("%-10s %-10s %s", name, effect, ratios)


if __name__ == "__main__":
    main()
