"""The separation safety layer: each agent's minimal filter of its commanded acceleration
(``filter``), its run-time view of the neighbours (``layer``), the small QP it solves."""
