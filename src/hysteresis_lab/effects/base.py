"""`Effect`: what a physical effect adds to a model and how residual evidence for it is scored."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np


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


class Effect:
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
