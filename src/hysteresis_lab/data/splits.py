"""`DatasetSplits`: the estimation/validation/test recordings of a data set, how to score it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from hysteresis_lab.data.recording import Recording, check_compatible
from hysteresis_lab.errors import DataError


@dataclass(frozen=True)
class DatasetSplits:
    """Recordings of one data set, split as its protocol prescribes.

    ``val`` may be empty: the DataModule then draws validation windows at random from
    ``train``. ``n_init`` is the number of samples at the start of each test recording that
    a model may use to initialise its state and that are excluded from scoring (the official
    benchmarks' state-initialisation window). ``shared_initial_state``: the protocol says every
    recording starts from one and the same unknown state (not rest), which a model that
    simulates from a state may learn on the training recordings and start every recording
    from (`hysteresis_lab.models.physical_chain`). ``output_integrates``: the measured output
    integrates what drives it (a position moved by a force, as on EMPS); the linear model
    then carries an integrator unless told otherwise (``model.integrator``).
    """

    name: str
    train: list[Recording]
    test: list[Recording]
    val: list[Recording] = field(default_factory=list)
    n_init: int = 0
    shared_initial_state: bool = False
    output_integrates: bool = False
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.train:
            raise DataError(
                "has no training recordings.",
                source=f"data set '{self.name}'",
                fix="supply at least one training recording",
            )
        check_compatible([*self.train, *self.val, *self.test], purpose=f"data set '{self.name}'")
        if self.n_init < 0:
            raise DataError(f"n_init={self.n_init} is negative.", source=f"data set '{self.name}'")

    @property
    def fs(self) -> float:
        return self.train[0].fs

    @property
    def nu(self) -> int:
        return self.train[0].nu

    @property
    def ny(self) -> int:
        return self.train[0].ny

    @property
    def units(self) -> dict[str, str]:
        return {"u": self.train[0].u_units, "y": self.train[0].y_units}
