"""An in-memory radio between the agents of one process: range, one-tick delay, link cuts (also
one-way), packet loss and extra delay, as the consensus estimator would meet them on a real network.

Pure apart from the injected random generator: no sockets, no clock; time is the round number.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence

import numpy as np

from drone_agent.consensus import ConsensusMessage
from drone_agent.link_faults import LinkFaults
from protocols.frames import FloatArray


class InProcessNetwork:
    """Delivers each round's messages to the drones in range, ``base_delay_ticks`` (≥ 1) later."""

    def __init__(
        self, n_drones: int, range_m: float, rng: np.random.Generator, base_delay_ticks: int = 1
    ) -> None:
        if base_delay_ticks < 1:
            raise ValueError("a message can arrive at the earliest one tick after it was sent")
        self.n = n_drones
        self.range_m = range_m
        self.rng = rng
        self.base_delay_ticks = base_delay_ticks
        self.conditions = LinkFaults()
        self._in_flight: dict[int, list[tuple[int, ConsensusMessage]]] = defaultdict(list)
        self.sent = 0
        self.delivered = 0
        self.lost = 0

    def in_range(self, positions_ned_m: FloatArray) -> FloatArray:
        """Boolean matrix (N, N): pairs within radio range (no self-links)."""
        d = np.linalg.norm(positions_ned_m[:, None, :] - positions_ned_m[None, :, :], axis=-1)
        ok: FloatArray = d < self.range_m
        np.fill_diagonal(ok, False)
        return ok

    def send(self, round_: int, messages: Sequence[ConsensusMessage], in_range: FloatArray) -> None:
        """Put this round's messages on the air; they reach receivers in range after the delay."""
        c = self.conditions
        for msg in messages:
            i = msg.sender
            for j in range(self.n):
                if j == i or not in_range[i, j]:
                    continue
                self.sent += 1
                if c.blocks(i, j):
                    self.lost += 1
                    continue
                loss = c.loss_for(i, j)
                if loss > 0.0 and self.rng.random() < loss:
                    self.lost += 1
                    continue
                delay = self.base_delay_ticks + c.delay_for(i, j)
                self._in_flight[round_ + delay].append((j, msg))

    def receive(self, round_: int) -> list[list[ConsensusMessage]]:
        """The inboxes (one list per drone) of messages that arrive at round ``round_``."""
        inboxes: list[list[ConsensusMessage]] = [[] for _ in range(self.n)]
        for j, msg in self._in_flight.pop(round_, []):
            inboxes[j].append(msg)
            self.delivered += 1
        return inboxes
