"""The consensus estimator's gains and timing (:class:`ConsensusParams`, with the step bound and
cap of drone_agent/core/consensus/scalar.py's doc) and the result of one round
(:class:`ConsensusOutput`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from protocols.model.frames import FloatArray
from protocols.wire.consensus_message import ConsensusMessage

STEP_BOUND = 0.7


@dataclass(frozen=True)
class ConsensusParams:
    """Gains and timing of the estimator. ``dt_s`` is the round period (control tick)."""

    rho: float = 2.0
    c: float = 1.0
    f: float = 2.0
    dt_s: float = 0.02
    degree_normalised: bool = False
    heard_timeout_ticks: int = 5
    history_ticks: int = 25
    max_step_gain: float = 1.4
    channel_scale_m: float = 10.0

    def validate(self) -> None:
        """Raise ValueError naming the first bad field."""
        for name in ("rho", "c", "f", "dt_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"consensus.{name} must be a positive number, got {value!r}")
        if not (np.isfinite(self.max_step_gain) and 0 <= self.max_step_gain < 2):
            raise ValueError(
                f"consensus.max_step_gain must be in [0, 2), got {self.max_step_gain!r}"
            )
        if not (np.isfinite(self.channel_scale_m) and self.channel_scale_m > 0):
            raise ValueError(
                f"consensus.channel_scale_m must be a positive number, got {self.channel_scale_m!r}"
            )
        if self.heard_timeout_ticks < 1:
            raise ValueError("consensus.heard_timeout_ticks must be at least 1")
        if self.history_ticks < self.heard_timeout_ticks:
            raise ValueError("consensus.history_ticks must be at least heard_timeout_ticks")

    @property
    def channel_scales(self) -> FloatArray:
        """Per channel (18,): ``L`` for the first moments, ``L^2`` for the second (the channel
        scale of the module doc, ``L = channel_scale_m``)."""
        length = self.channel_scale_m
        first, second = np.full(3, length), np.full(6, length * length)
        return np.concatenate([first, second, first, second])

    @property
    def rho_cap(self) -> float:
        """``rho_e * max(d_i, d_j)`` never exceeds this (the step cap of the module doc); inf
        without a cap (``max_step_gain`` 0)."""
        if self.max_step_gain <= 0:
            return float("inf")
        return self.max_step_gain / (2.0 * self.f * self.c * self.dt_s)

    def step_gain(self, lambda_max: float) -> float:
        """``f rho c dt lambda_max(L)`` of the fixed-gain update on a graph with that largest
        Laplacian eigenvalue; keep it at or below :data:`STEP_BOUND` on the worst graph."""
        return self.f * self.rho * self.c * self.dt_s * lambda_max

    def within_step_bound(self, lambda_max: float) -> bool:
        """The discrete-time step bound of ALGORITHM.md §3 rule 6.

        Degree-normalised gain: rho c <= 8."""
        if self.degree_normalised:
            return self.rho * self.c <= 8.0
        return self.step_gain(lambda_max) <= STEP_BOUND


@dataclass(frozen=True)
class ConsensusOutput:
    """Result of one round: the estimate (18,) of the channel averages, the message to send, the
    neighbours whose edge integrated in this round (sorted), and the relative disagreement: the
    largest ``|gamma_i - gamma_j| / (1 + max(|gamma_i|, |gamma_j|))`` over the channels and the
    pairs integrated in this round (0 if none), small once the estimator has settled."""

    estimate: FloatArray
    message: ConsensusMessage
    active_neighbours: tuple[int, ...]
    disagreement: float = 0.0
