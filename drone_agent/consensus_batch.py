"""The consensus estimator of K agents at once, by its old module name: its parts are
drone_agent/consensus_estimator.py (:class:`BatchConsensus`), consensus_packing.py (the step's
messages as arrays) and consensus_kernels.py (the compiled loops), and
:func:`~protocols.fast_dataclass.frozen_factory` is in protocols. Kept for the callers that still
import these names from here."""

from __future__ import annotations

from drone_agent.consensus_estimator import BatchConsensus
from drone_agent.consensus_packing import (
    Outgoing,
    from_step,
    message_columns,
    packed_motion,
    with_level,
)
from protocols.fast_dataclass import frozen_factory

__all__ = [
    "BatchConsensus",
    "Outgoing",
    "from_step",
    "frozen_factory",
    "message_columns",
    "packed_motion",
    "with_level",
]
