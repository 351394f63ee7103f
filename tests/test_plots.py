"""Pictures of a flight (gcs.report.plots): PNG files of the expected size, made headless."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from gcs.report.flight_record import FlightRecord, LinkFault
from gcs.report.metrics import true_descriptors
from gcs.report.plots import DPI, plot_controls, plot_descriptors, plot_paths, write_plots

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def flight(n: int = 4, duration_s: float = 20.0, square: bool = False) -> FlightRecord:
    """A formation flying north and climbing; drone 2 (index 1) lost half way; two link cuts."""
    t = np.round(np.arange(0.0, duration_s, 0.05), 9)
    rng = np.random.default_rng(0)
    angle = 2 * np.pi * np.arange(n) / n
    offsets = np.stack(
        [3.0 * np.cos(angle), (3.0 if square else 1.5) * np.sin(angle), 0 * angle], 1
    )
    centre = np.stack([2.0 * t, 0.3 * np.sin(t), -np.minimum(t, 5.0)], axis=1)
    pos = centre[:, None, :] + offsets + 0.05 * rng.standard_normal((t.size, n, 3))
    member = np.ones((t.size, n), dtype=bool)
    t_lost = duration_s / 2
    member[t > t_lost, 1] = False
    desired = np.zeros((t.size, 9))
    desired[:, :3] = centre
    desired[:, 6:] = [4.5, 1.125, 0.0]
    euler = 0.1 * np.sin(t)[:, None, None] * np.ones((1, n, 3))
    rec = FlightRecord(
        t_s=t,
        position_ned_m=pos,
        velocity_ned_m_s=np.gradient(pos, t, axis=0),
        euler_rad=euler,
        thrust_n=3.3 + 0.3 * np.cos(t)[:, None] * np.ones((1, n)),
        moments_nm=0.01 * np.sin(t)[:, None, None] * np.ones((1, n, 3)),
        desired=desired,
        estimate=np.full((t.size, n, 9), np.nan),
        member=member,
        airborne=np.ones((t.size, n), dtype=bool),
        neighbours=np.full((t.size, n), n - 1),
        link_faults=[LinkFault(3.0, 6.0, 0, 2), LinkFault(12.0, 13.0, 2, 3, one_way=True)],
        lost_at_s={1: t_lost},
    )
    a = true_descriptors(rec)
    rec.estimate = a[:, None, :] + 0.02 * rng.standard_normal((t.size, n, 9))
    return rec


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE and data[12:16] == b"IHDR"
    width, height = struct.unpack(">II", data[16:24])
    return width, height


@pytest.fixture(scope="module")
def record() -> FlightRecord:
    return flight()


def test_write_plots_makes_three_pngs_in_a_new_folder(tmp_path, record):
    out = tmp_path / "report" / "plots"
    paths = write_plots(record, out)
    assert [p.name for p in paths] == ["paths.png", "descriptors.png", "controls.png"]
    for p in paths:
        assert p.parent == out and p.stat().st_size > 30_000
        width, height = png_size(p)
        assert 1000 <= width <= 2500 and 600 <= height <= 1500


@pytest.mark.parametrize(
    ("plot", "inches"),
    [(plot_paths, (16, 6.5)), (plot_descriptors, (15, 10)), (plot_controls, (13, 10))],
)
def test_each_plot_has_its_figure_size(tmp_path, record, plot, inches):
    path = plot(record, tmp_path / "x.png")
    assert png_size(path) == (round(inches[0] * DPI), round(inches[1] * DPI))


def test_plots_leave_pyplot_alone(tmp_path, record):
    import matplotlib
    import matplotlib.pyplot as plt

    backend, figures = matplotlib.get_backend(), plt.get_fignums()
    plot_descriptors(record, tmp_path / "d.png")
    assert matplotlib.get_backend() == backend and plt.get_fignums() == figures


def test_undefined_heading_many_drones_and_no_faults_still_plot(tmp_path):
    rec = flight(n=24, duration_s=6.0, square=True)
    rec.link_faults, rec.lost_at_s = [], {}
    for p in write_plots(rec, tmp_path):
        assert p.stat().st_size > 20_000
