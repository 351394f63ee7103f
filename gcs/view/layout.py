"""The viewer's layout for a swarm: the Rerun blueprint every recording and live view carries.

Left, the largest view: the 3-D swarm (``swarm/**`` of :mod:`gcs.view.rerun_log`: drones
coloured by mode, trails, radio links, the commanded and the true formation ellipsoids, the
commanded formation's frame, the agents' centre estimates). Right, the descriptor panel: one plot
per descriptor (centre north, east, altitude; heading, pitch, roll, each with its error on its own
plot below it; the length, width and height variances), each with the command, the true value and
the agents' estimates on the same axes, over the whole flight; behind it, a tab with the minimum
separation, the consensus error and the radio links. Across the bottom, full width, the events log
(time, level, text). The time panel shows the simulated time (``sim_time``).

The user can change the layout in the viewer (and go back to this one with "reset blueprint");
``--layout auto`` leaves it to Rerun's automatic layout (:data:`LAYOUTS`).
"""

from __future__ import annotations

import rerun.blueprint as rrb

from gcs.view.rerun_series import ANGLES, DESCRIPTOR_PLOTS, TIMELINE

#: ``--layout`` choices: this module's layout, or Rerun's automatic one.
LAYOUTS = ("swarm", "auto")
#: The plots' time axis: the whole flight (so far), as descriptors.png (Rerun's default range
#: shows only about the last 40 s of a 200-s replay); each plot zooms on its own.
_WHOLE_FLIGHT = rrb.TimeRange(
    start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite()
)
#: Width of the 3-D view and of the plots, and height of the views and of the events log.
COLUMN_SHARES = (3.0, 2.0)
ROW_SHARES = (4.0, 1.0)


def blueprint() -> rrb.Blueprint:
    """The swarm layout (the same for every flight: it names entities, not drones)."""
    top = rrb.Horizontal(
        rrb.Spatial3DView(name="swarm", origin="swarm"),
        rrb.Tabs(
            rrb.Grid(*_descriptor_views(), grid_columns=3, name="descriptors"),
            rrb.Grid(*_health_views(), grid_columns=2, name="separation, consensus, links"),
            active_tab=0,
        ),
        column_shares=list(COLUMN_SHARES),
    )
    events = rrb.TextLogView(
        name="events",
        origin="events",
        columns=rrb.TextLogColumns(
            timeline_columns=[TIMELINE], text_log_columns=["loglevel", "body"]
        ),
    )
    return rrb.Blueprint(
        rrb.Vertical(top, events, row_shares=list(ROW_SHARES)),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline=TIMELINE),
    )


def layout_blueprint(layout: str) -> rrb.Blueprint | None:
    """The blueprint of ``layout`` (one of :data:`LAYOUTS`): None for Rerun's own."""
    if layout not in LAYOUTS:
        raise ValueError(f"unknown layout {layout!r} (one of {', '.join(LAYOUTS)})")
    return blueprint() if layout == "swarm" else None


def _plot(name: str, contents: list[str]) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(
        name=name,
        origin="/",
        contents=contents,
        plot_legend=rrb.PlotLegend(visible=False),
        axis_x=rrb.TimeAxis(view_range=_WHOLE_FLIGHT),
    )


def _descriptor_views() -> list[rrb.TimeSeriesView]:
    """Rows of three: centre; angles; the angles' errors; variances."""
    views = []
    for _, name, title in DESCRIPTOR_PLOTS:
        path = f"/descriptors/{name}"
        views.append(_plot(title, [f"{path}/estimates", f"{path}/actual", f"{path}/commanded"]))
    errors = [
        _plot(f"Δ {title}", [f"/descriptors/{name}/error"])
        for k, name, title in DESCRIPTOR_PLOTS
        if k in ANGLES
    ]
    return views[:6] + errors + views[6:]


def _health_views() -> list[rrb.TimeSeriesView]:
    return [
        _plot("minimum separation [m]", ["/separation/min_m"]),
        _plot("worst consensus error of the centre [m]", ["/consensus/error_m"]),
        _plot("mean neighbours per agent", ["/links/neighbours_mean"]),
        _plot("radio links (pairs)", ["/links/pairs"]),
    ]
