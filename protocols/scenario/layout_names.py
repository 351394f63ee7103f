"""The names of the layouts a generated swarm starts in (placed by
:func:`protocols.scenario.layout.layout_positions`), in a module of their own: the command line
offers them (``swarm scenario new --layout``, ``swarm up --layout``) without importing numpy."""

from __future__ import annotations

LAYOUTS = ("grid", "line", "circle", "random")
