"""PNG pictures of a flight, like the paper's Fig. 4-6: paths, descriptors against the command,
and control inputs per drone.

Drones are labelled by MAVLink system id (drone n = index n - 1). The pictures are drawn on
``matplotlib.figure.Figure`` objects rendered by the Agg canvas, never through pyplot, so they work
headless and leave matplotlib's global backend and figure registry alone.

Top views are true maps turned a quarter: x north to the right, y east *downwards* (the y axis is
inverted), so the picture is not mirrored. The 3-D view likewise inverts the east axis.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, cast

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d.axes3d import Axes3D

from gcs.report.flight_record import FlightRecord
from gcs.report.metrics import BoolArray, heading_mask, true_descriptors
from protocols.model.descriptor_vector import I_PITCH, I_ROLL, I_YAW
from protocols.model.frames import FloatArray, wrap_pi

DPI = 110
_MAX_POINTS = 20_000
_LINK_COLOUR = "tab:orange"


_ERROR_COLOUR = "tab:red"


def _colours(n: int) -> list[Any]:
    """One colour per drone."""
    import matplotlib as mpl

    cmap = mpl.colormaps["tab10" if n <= 10 else "tab20" if n <= 20 else "viridis"]
    return [cmap(i if n <= 20 else i / max(1, n - 1)) for i in range(n)]


def _stride(t_s: FloatArray) -> slice:
    return slice(None, None, max(1, int(np.ceil(t_s.shape[0] / _MAX_POINTS))))


def _until_lost(record: FlightRecord) -> FloatArray:
    """Positions (T, N, 3) with NaN after each lost drone's loss time."""
    x = record.position_ned_m.copy()
    for i, t_lost in record.lost_at_s.items():
        x[record.t_s > t_lost, i] = np.nan
    return x


def _save(fig: Figure, path: str | Path) -> Path:
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(out, dpi=DPI)
    return out


def _snapshot_indices(t_s: FloatArray) -> list[int]:
    """Sample indices of formation snapshots: a round interval giving about 4-8 snapshots."""
    duration = float(t_s[-1] - t_s[0]) if t_s.size else 0.0
    step = next((s for s in (5, 10, 20, 25, 50, 100, 200, 500) if duration / s <= 8), 1000)
    times = [*np.arange(t_s[0], t_s[-1], step), t_s[-1]] if t_s.size else []
    idx = sorted({int(np.argmin(np.abs(t_s - tt))) for tt in times})
    return idx


def plot_paths(record: FlightRecord, path: str | Path) -> Path:
    """Top view (x north right, y east down) with formation snapshots, and a 3-D view."""
    fig = Figure(figsize=(16, 6.5), layout="constrained")
    grid = fig.add_gridspec(1, 2, width_ratios=(1.35, 1.0))
    top = fig.add_subplot(grid[0])
    ax3 = cast(Axes3D, fig.add_subplot(grid[1], projection="3d"))
    x = _until_lost(record)
    colours = _colours(record.n_drones)
    sl = _stride(record.t_s)
    for i in range(record.n_drones):
        xi = x[sl, i]
        top.plot(xi[:, 0], xi[:, 1], lw=0.9, color=colours[i], label=f"drone {i + 1}")
        ax3.plot(xi[:, 0], xi[:, 1], -xi[:, 2], lw=0.9, color=colours[i])
        if i in record.lost_at_s:
            last = x[np.isfinite(x[:, i, 0]), i]
            if last.size:
                top.plot(*last[-1, :2], "x", color="red", ms=9, mew=2)
                ax3.plot(*last[-1, :2], -last[-1, 2], "x", color="red", ms=9, mew=2)
    for k in _snapshot_indices(record.t_s):
        pts = x[k][record.member[k] & np.isfinite(x[k, :, 0])]
        if pts.size == 0:
            continue
        top.plot(pts[:, 0], pts[:, 1], "o", color="black", ms=3.5, zorder=5)
        top.annotate(
            f"{record.t_s[k]:.0f} s",
            (pts[:, 0].mean(), pts[:, 1].min()),
            xytext=(0, 4),
            textcoords="offset points",
            ha="center",
            va="bottom",
            fontsize=8,
            bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8},
        )
    top.invert_yaxis()
    top.set(xlabel="x north [m]", ylabel="y east [m] (east is down)")
    top.set_title("Top view: paths and formation snapshots (black dots)")
    top.grid(alpha=0.3)
    extra = [Line2D([], [], color="black", marker="o", ls="", ms=4, label="formation snapshot")]
    if record.lost_at_s:
        extra.append(Line2D([], [], color="red", marker="x", ls="", mew=2, label="drone lost"))
    handles = [*top.get_legend_handles_labels()[0][: 20 if record.n_drones <= 20 else 0], *extra]
    fig.legend(handles=handles, fontsize=8, loc="outside lower center", ncol=min(12, len(handles)))
    span = np.array([np.ptp(v[np.isfinite(v)]) if np.isfinite(v).any() else 1.0 for v in x.T])
    ax3.set_box_aspect(
        tuple(np.clip(span / max(span.max(), 1e-9), 0.55, 1.0) * [1.5, 1.0, 0.8]), zoom=0.88
    )
    ax3.invert_yaxis()
    for axis in (ax3.xaxis, ax3.yaxis, ax3.zaxis):
        axis.set_major_locator(MaxNLocator(5))
    ax3.set_xlabel("x north [m]")
    ax3.set_ylabel("y east [m]")
    ax3.set_zlabel("altitude [m]")
    ax3.set_title("3-D view")
    many = "; colour by drone index (viridis)" if record.n_drones > 20 else ""
    fig.suptitle(f"Paths of {record.n_drones} drones over {record.t_s[-1]:.0f} s{many}")
    return _save(fig, path)


def _runs(mask: BoolArray, t_s: FloatArray) -> list[tuple[float, float]]:
    """Time intervals [t0, t1] over which ``mask`` (T,) holds."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [(float(t_s[a]), float(t_s[b])) for a, b in zip(starts, ends, strict=True)]


_PANELS: tuple[tuple[int, str], ...] = (
    (0, r"centre $\mu_x$ (north) [m]"),
    (1, r"centre $\mu_y$ (east) [m]"),
    (2, r"altitude $-\mu_z$ [m]"),
    (I_YAW, "heading (yaw) [deg]"),
    (I_PITCH, "pitch [deg]"),
    (I_ROLL, "roll [deg]"),
    (6, r"$s_l$ (length variance) [m$^2$]"),
    (7, r"$s_w$ (width variance) [m$^2$]"),
    (8, r"$s_h$ (height variance) [m$^2$]"),
)


def _display(values: FloatArray, desired: FloatArray, k: int) -> FloatArray:
    """Values of descriptor ``k`` as plotted: altitude up, angles in degrees near the command."""
    if k == 2:
        return -values
    if k in (I_ROLL, I_PITCH, I_YAW):
        return np.degrees(desired + wrap_pi(values - desired))
    return values


def plot_descriptors(record: FlightRecord, path: str | Path) -> Path:
    """3 x 3 grid: each descriptor true (centralised), each agent's estimate, and the command."""
    fig = Figure(figsize=(15, 10), layout="constrained")
    axes = fig.subplots(3, 3, sharex=True)
    t, sl = record.t_s, _stride(record.t_s)
    a_true, a_d = true_descriptors(record), record.desired
    ok = heading_mask(a_true)
    undefined = _runs(~ok & np.all(np.isfinite(a_true), axis=1), t)
    est = np.where(record.member[..., None], record.estimate, np.nan)
    for ax, (k, title) in zip(axes.flat, _PANELS, strict=True):
        true_k, est_k = a_true[:, k].copy(), est[:, :, k].copy()
        if k in (I_ROLL, I_PITCH, I_YAW):
            true_k[~ok], est_k[~ok] = np.nan, np.nan
            for t0, t1 in undefined:
                ax.axvspan(t0, t1, color="0.75", alpha=0.6, lw=0)
        ax.plot(t[sl], _display(est_k, a_d[:, k : k + 1], k)[sl], color="0.55", lw=0.5, alpha=0.7)
        ax.plot(t[sl], _display(true_k, a_d[:, k], k)[sl], color="tab:blue", lw=1.4)
        ax.plot(t[sl], _display(a_d[:, k], a_d[:, k], k)[sl], "k--", lw=1.0)
        _fault_marks(ax, record)
        if k in (I_ROLL, I_PITCH, I_YAW):
            _angle_limits(ax, _display(true_k, a_d[:, k], k), np.degrees(a_d[:, k]))
            # the error on its own scale: sub-degree tracking is invisible on the angle's
            error = np.degrees(wrap_pi(true_k - a_d[:, k]))
            twin = ax.twinx()
            twin.plot(t[sl], error[sl], color=_ERROR_COLOUR, lw=0.8)
            twin.tick_params(axis="y", colors=_ERROR_COLOUR, labelsize=8)
            twin.set_ylabel("error [deg]", color=_ERROR_COLOUR, fontsize=8)
            finite = error[np.isfinite(error)]
            bound = max(0.1, 1.1 * float(np.abs(finite).max())) if finite.size else 1.0
            twin.set_ylim(-bound, bound)
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    fig.legend(
        handles=_descriptor_legend(record, bool(undefined)), loc="outside lower center", ncol=7
    )
    lost = ", ".join(f"drone {i + 1} at {ts:.1f} s" for i, ts in sorted(record.lost_at_s.items()))
    fig.suptitle(
        "Swarm descriptors against the command"
        + (f"; lost: {lost}" if lost else "")
        + (f"; {len(record.link_faults)} link cuts (shaded)" if record.link_faults else "")
    )
    return _save(fig, path)


def _fault_marks(ax: Axes, record: FlightRecord) -> None:
    """Shade link-cut intervals and draw a red dotted line at each drone loss."""
    for lf in record.link_faults:
        ax.axvspan(lf.t0_s, lf.t1_s, color=_LINK_COLOUR, alpha=0.08 if lf.one_way else 0.15, lw=0)
    for t_lost in record.lost_at_s.values():
        ax.axvline(t_lost, color="red", ls=":", lw=1.2)


def _angle_limits(ax: Axes, true_deg: FloatArray, desired_deg: FloatArray) -> None:
    """Y limits from the true and commanded angle (estimates may leave the frame), ±5° at least."""
    vals = np.concatenate([true_deg[np.isfinite(true_deg)], desired_deg[np.isfinite(desired_deg)]])
    if vals.size == 0:
        return
    lo, hi = float(vals.min()), float(vals.max())
    mid, half = (lo + hi) / 2, max(5.0, 0.55 * (hi - lo))
    ax.set_ylim(mid - half, mid + half)


def _descriptor_legend(record: FlightRecord, heading_undefined: bool) -> list[Any]:
    handles: list[Any] = [
        Line2D([], [], color="tab:blue", lw=1.4, label="true (centralised)"),
        Line2D([], [], color="0.55", lw=0.8, label="estimate of each agent"),
        Line2D([], [], color="black", ls="--", lw=1.0, label="command"),
        Line2D([], [], color=_ERROR_COLOUR, lw=0.8, label="angle error (right axis)"),
    ]
    if record.link_faults:
        handles.append(Patch(color=_LINK_COLOUR, alpha=0.3, label="link cut"))
    if record.lost_at_s:
        handles.append(Line2D([], [], color="red", ls=":", lw=1.2, label="drone lost"))
    if heading_undefined:
        handles.append(Patch(color="0.75", label=r"heading undefined ($s_l \approx s_w$)"))
    return handles


def plot_controls(record: FlightRecord, path: str | Path) -> Path:
    """Collective thrust and roll, pitch, yaw moments of each drone over time (4 panels)."""
    fig = Figure(figsize=(13, 10), layout="constrained")
    axes = fig.subplots(4, 1, sharex=True)
    t, sl = record.t_s, _stride(record.t_s)
    thrust, moments = record.thrust_n.copy(), record.moments_nm.copy()
    for i, t_lost in record.lost_at_s.items():
        thrust[t > t_lost, i] = np.nan
        moments[t > t_lost, i] = np.nan
    series = (thrust, moments[..., 0], moments[..., 1], moments[..., 2])
    labels = (
        "collective thrust [N]",
        "roll moment [N m]",
        "pitch moment [N m]",
        "yaw moment [N m]",
    )
    colours = _colours(record.n_drones)
    for ax, values, label in zip(axes, series, labels, strict=True):
        for i in range(record.n_drones):
            ax.plot(t[sl], values[sl, i], color=colours[i], lw=0.7, label=f"drone {i + 1}")
        _fault_marks(ax, record)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("t [s]")
    if record.n_drones <= 20:
        fig.legend(*axes[0].get_legend_handles_labels(), loc="outside right upper", fontsize=8)
    many = "; colour by drone index (viridis)" if record.n_drones > 20 else ""
    fig.suptitle(f"Control inputs of each drone (drone n = MAVLink system id n){many}")
    return _save(fig, path)


def write_plots(record: FlightRecord, out_dir: str | Path) -> list[Path]:
    """Write paths.png, descriptors.png and controls.png into ``out_dir``; returns their paths."""
    out = Path(out_dir)
    return [
        plot_paths(record, out / "paths.png"),
        plot_descriptors(record, out / "descriptors.png"),
        plot_controls(record, out / "controls.png"),
    ]
