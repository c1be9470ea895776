"""`Effect`: one physical effect with all its faces, and `Block`, what every block of a plant
shares with it.

An effect owns, in its one file (`hysteresis_lab.effects.<name>`):

* where it sits in a plant: `Block.place` (input, dynamics, feedback, output) and
  `Block.rank` (its order there), data on the class;
* its diagnosis face: the operators a network takes in (`Effect.features`) and the evidence
  the diagnosis scores (`Effect.evidence`, `Effect.state_evidence`, `Effect.output_evidence`);
* its simulator face: the parameters of its simulator block (`Block.sim_config`, a dataclass
  read from ``data.effects.<sim_key>``) and the block (`Block.simulate`); an effect without
  one is simply not simulatable;
* its trainable faces: the block(s) ``model=linear`` builds for it (`Effect.linear_blocks`)
  and what ``model=greybox`` carries of it (`Effect.greybox_part`); an effect without one is
  not carried by that model.

Models and the simulator build their chains by iterating over these objects in physical
order (`physical_order`), never by the effects' names.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

if TYPE_CHECKING:
    from torch import nn

#: where a block sits in a plant, in signal order: ahead of the dynamics (on the drive), in
#: the dynamics (on the displacement / the linear response), in their feedback, after them
PLACES = ("input", "dynamics", "feedback", "output")


@dataclass(frozen=True)
class FeatureContext:
    """Facts an operator may depend on, fixed when the model is built (saved with it)."""

    fs: float
    u_amplitude: np.ndarray  # (nu,) max |u| of the training input, sets operator thresholds
    duration_s: float  # of the training recording, bounds the slowest time constant
    #: (ny,) lowest and highest measured output of the training recordings (output-side
    #: blocks start their levels there); None in contexts saved before they were kept
    y_low: np.ndarray | None = None
    y_high: np.ndarray | None = None
    #: (ny,) smallest and largest step of the measured output from one sample to the next
    #: (a model whose output integrates places its blocks there); None where not kept
    dy_low: np.ndarray | None = None
    dy_high: np.ndarray | None = None


#: blocks whose evidence is read from the model's own free-run output (`Effect.output_evidence`)
MODEL_OUTPUT_BLOCKS = ("output", "feedback")


@dataclass
class PlantSignals:
    """The signals of a simulated plant as its blocks pass them on (`Block.simulate`): the
    drive ``v`` (input place), the displacement ``x`` (dynamics place, set where the drive
    becomes a displacement), the output ``y`` (output place, set where the structure's
    dynamics act), plus what a block leaves for a later one."""

    fs: float
    rng: np.random.Generator
    v: np.ndarray
    x: np.ndarray | None = None
    y: np.ndarray | None = None
    #: per-sample factor of the hysteresis' ``alpha`` (rate-dependent hysteresis), or None
    alpha_factor: np.ndarray | None = None


class Block:
    """A block of a plant: where it sits and, where it has one, its simulator face.

    ``place`` is one of `PLACES`; ``rank`` orders blocks within a place (the physical order:
    a clipping amplifier before a dead zone before a backlash ...; models grow declared
    effects in this order). ``sim_config`` is the dataclass of the block's parameters, read
    from ``data.effects.<sim_key>`` (an ``enabled`` switch among them); None: the block has no
    simulator face. ``sim_rank`` is the block's order in the simulator's chain where it
    differs from ``rank`` (a block that sets what a later block reads)."""

    place: ClassVar[str] = "input"
    rank: ClassVar[int] = 0
    sim_config: ClassVar[type | None] = None
    sim_rank: ClassVar[int | None] = None

    @property
    def sim_key(self) -> str:
        """Its key under ``data.effects`` (the simulator's config)."""
        return getattr(self, "name", "")

    @property
    def simulatable(self) -> bool:
        return self.sim_config is not None

    def sim_order(self) -> tuple[int, int]:
        """Its position in the simulator's chain."""
        return (PLACES.index(self.place),
                self.rank if self.sim_rank is None else self.sim_rank)

    def simulate(self, plant: PlantSignals, cfg: Any) -> None:
        """Act on ``plant``'s signals with the parameters ``cfg`` (an instance of
        ``sim_config``, enabled): an input block changes ``plant.v``, a dynamics block
        ``plant.x``, an output block ``plant.y``."""
        raise NotImplementedError(f"block '{self.sim_key}' has no simulator face")

    def simulate_disabled(self, plant: PlantSignals, cfg: Any) -> None:
        """What the plant does where the block is switched off (default: nothing; a block
        that turns one signal into the next passes it on)."""

    def validate(self, cfg: Any, key: str) -> list[str]:
        """Problems of the parameters ``cfg`` (enabled) as lines ``key.parameter=...``."""
        return []

    def validate_any(self, cfg: Any, key: str) -> list[str]:
        """Problems of the parameters ``cfg`` whether the block is on or off."""
        return []

    def validate_rate(self, cfg: Any, key: str, fs: float) -> list[str]:
        """Problems of the parameters ``cfg`` (enabled) at the sampling rate ``fs`` (Hz)."""
        return []


@dataclass
class LinearContext:
    """What an effect's ``model=linear`` blocks are built from: the measured inputs'
    amplitudes and the outputs' ranges over their scales, the rate, the model's settings
    and the effects declared with it."""

    fs: float
    n_inputs: int
    n_outputs: int
    input_amplitude: Callable[[int], float]
    #: per output, the range the output-side blocks start at, and the range the loop forces
    #: read (the output's, or with an integrator its steps')
    output_extremes: Sequence[tuple[float, float]]
    forced_extremes: Sequence[tuple[float, float]]
    settings: Mapping[str, Any]
    declared: Sequence[Effect] = field(default_factory=list)


@dataclass(frozen=True)
class LinearBlock:
    """One block an effect adds to ``model=linear``.

    ``site``: ``"series"`` (per measured input, in series ahead of the dynamics),
    ``"parallel"`` (per output and input, in parallel with the dynamics), ``"force"`` (per
    output and input, a force with states in the dynamics' feedback: one at most),
    ``"law"`` (per output and input, a static law of the output in that feedback: one at
    most) or ``"output"`` (per output, on the output itself). ``make(context, index)`` builds
    it (``index``: the input, the output, or the ``(output, input)`` pair). ``attribute``:
    the model's container for it (its state-dict prefix); None: a series block kept with the
    input's other static blocks (``input_blocks.<j>.<key>``). ``key``: its name there
    (default: the effect's name; two effects naming one key share the block)."""

    site: str
    make: Callable[[LinearContext, Any], nn.Module]
    attribute: str | None = None
    key: str | None = None


@dataclass(frozen=True)
class GreyBoxPart:
    """What ``model=greybox`` carries of an effect: ``series`` builds a block per input
    after the hysteresis cell and the gain (``series(fs, settings)``, kept as ``attribute``
    on one axis and ``attribute_mimo`` per input on MIMO data); ``extra_modes`` adds modes to
    the structure's; ``in_cell``: the model's own hysteresis cell carries it; ``cell_term``
    builds a term added to the cell's output from the cell's input (``cell_term(amplitude)``,
    the input's amplitude over its scale; kept as ``attribute`` / ``attribute_mimo``)."""

    series: Callable[[float, Mapping[str, Any]], nn.Module] | None = None
    cell_term: Callable[[float], nn.Module] | None = None
    attribute: str | None = None
    attribute_mimo: str | None = None
    extra_modes: int = 0
    in_cell: bool = False


def physical_order(blocks: Sequence[Block]) -> list[Any]:
    """``blocks`` sorted by place, then rank (the order the physics puts them in)."""
    return sorted(blocks, key=lambda b: (PLACES.index(b.place), b.rank))


class Effect(Block):
    """A physical effect: input operators computed from ``u`` (N x nu) -> (N x k).

    ``features`` is what a model that declares the effect receives as extra input channels;
    ``evidence`` is the set of candidate signals the diagnosis regresses the residual on
    (by default the same operators). ``predictable`` is False for effects that do not depend
    on the input (drift): a model can fit them one step ahead but not in free run.
    ``block`` is where a network takes the operators in: ``"network"`` (extra inputs, or the
    linear effect path with ``model.effect_path=linear``) or ``"input"`` (a static
    nonlinearity ahead of the dynamics: each measured input becomes ``u + W @ operators``,
    one weight per operator, and the network sees the corrected input) or ``"output"`` (it
    acts after the dynamics, on the model's own output: overflow, output clipping; it has no
    input operators, only models with an output block carry it, and the diagnosis reads its
    evidence from the model's free-run output, `output_evidence`) or ``"feedback"`` (a static
    law of the model's own output fed back into its dynamics, a Lur'e system: read like
    ``"output"``, carried only by models with such a loop).
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    predictable: ClassVar[bool] = True
    block: ClassVar[str] = "network"
    #: simpler effects whose evidence overlaps this one's: the diagnosis calls it
    #: significant only when it is also significant beyond the signals of those the model
    #: does not carry yet
    beyond: ClassVar[tuple[str, ...]] = ()

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        raise NotImplementedError

    def evidence(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        return self.features(u, ctx)

    def state_evidence(self, y_model: np.ndarray, span: tuple[float, float]) -> np.ndarray | None:
        """Candidate signals of the effect acting inside the dynamics, from the model's own
        free-run output (a hysteretic restoring force depends on the displacement's
        history); None: the effect has none. They join `evidence` in the diagnosis."""
        return None

    def output_evidence(self, y_model: np.ndarray, span: tuple[float, float]) -> np.ndarray:
        """An output-side effect's candidate signals from the model's own free-run output
        ``y_model`` (N,), ``span`` its (lowest, highest) value over the recordings diagnosed
        together (one law for all of them)."""
        raise NotImplementedError(f"effect '{self.name}' does not act on the output")

    def unshown(
        self, ctx: FeatureContext, settings: Mapping[str, Any] | None = None
    ) -> str | None:
        """What of the effect training data of ``ctx`` (their duration and rate) cannot show,
        and what data would: one line for a warning; None where they can show all of it.
        ``settings``: the model's config (an effect may read its own time scales there)."""
        return None

    # ------------------------------------------------------------------ trainable faces
    #: ``model=linear`` refits the whole model when a loop round adds it (its block reshapes
    #: what the fitted blocks were fitted to); read by `hysteresis_lab.workflows.grow`
    linear_whole_refit: ClassVar[bool] = False
    #: a loop refit that adds it to ``model=linear`` tries its law on the whole dynamics and
    #: on the output stage's own level (a storage's outflow law, its rim)
    linear_tries_output_stage: ClassVar[bool] = False

    def linear_blocks(self, ctx: LinearContext) -> list[LinearBlock]:
        """The blocks ``model=linear`` builds for the effect, each starting where it changes
        nothing; empty: ``model=linear`` does not carry it."""
        return []

    @property
    def linear_carried(self) -> bool:
        """Whether ``model=linear`` carries it (it overrides `linear_blocks`)."""
        return type(self).linear_blocks is not Effect.linear_blocks

    def linear_storage_rim(self, low: float, high: float) -> float | None:
        """With ``model.feedback_on=output_stage``: the level of a rim the effect puts on the
        upstream storage for an output of range ``low``-``high``; None: no rim."""
        return None

    def greybox_part(self) -> GreyBoxPart | None:
        """What ``model=greybox`` carries of the effect; None: it does not."""
        return None
