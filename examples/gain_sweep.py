"""Sweep the consensus gain rho over five seeds and plot the estimate error (notebook style:
each ``# %%`` cell runs on its own in Jupyter or VS Code; or run the whole file).

Each run is a short scenario file (4 drones climb to 3 m and hover, 30 % packet loss from 9 s)
flown by :meth:`gcs.api.Swarm.start` in lockstep on free ports; the seed draws the losses. The
figure is each run's consensus error on the formation's shape: the RMS error of the agents'
estimates of the three variances after the settling time, from the run's report
(:class:`gcs.api.FlightReport`, metrics computed as ``metrics.json``'s).

    .venv/bin/python examples/gain_sweep.py --out sweep      # ten flights, ~2 min on two cores
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from gcs.api import Swarm
from protocols.scenario.generator import GeneratorOptions, generate, parse_faults

# %% the sweep
parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--out", type=Path, default=Path("sweep"), help="where runs and plot go")
parser.add_argument("--gains", type=float, nargs="+", default=[1.0, 4.0], help="rho values")
parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
args = parser.parse_args()
args.out.mkdir(parents=True, exist_ok=True)


def scenario_file(rho: float, seed: int) -> Path:
    """A 20 s hover of 4 drones with 30 % loss from 9 s, consensus gain ``rho``."""
    options = GeneratorOptions(
        drones=4, template="hover", duration_s=20.0, seed=seed,
        faults=parse_faults("loss=0.3"), name=f"rho{rho:g}-seed{seed}",
    )  # fmt: skip
    path = args.out / f"rho{rho:g}-seed{seed}.toml"
    text = generate(options, str(path), "examples/gain_sweep.py").text
    path.write_text(text.replace("[consensus]\n", f"[consensus]\nrho = {rho}\n", 1))
    return path


errors: dict[float, list[float]] = {}
for rho in args.gains:
    for seed in args.seeds:
        run = args.out / f"rho{rho:g}-seed{seed}"
        with Swarm.start(scenario_file(rho, seed), report=run) as swarm:
            swarm.wait_end(timeout_s=300)
        assert swarm.report is not None, swarm.end_reason
        rms = swarm.report.metrics()["consensus"]["shape_m2"]["rms"]
        errors.setdefault(rho, []).append(rms)
        print(f"rho {rho:g} seed {seed}: shape estimate error {rms:.4f} m² RMS")

# %% the plot
fig, ax = plt.subplots(figsize=(5, 3.5))
for rho, values in errors.items():
    ax.plot([rho] * len(values), values, "o", alpha=0.6)
    ax.plot([rho], [sum(values) / len(values)], "k_", markersize=20)
ax.set_xlabel("consensus gain rho")
ax.set_ylabel("shape estimate error, RMS (m²)")
ax.set_title(f"4 drones, 30 % loss, {len(args.seeds)} seeds per gain")
fig.tight_layout()
fig.savefig(args.out / "gain_sweep.png", dpi=100)
print(f"wrote {args.out / 'gain_sweep.png'}")
