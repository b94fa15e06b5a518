"""What a gv run reports of its wind (scenarios with a `wind` section): metrics.json's `wind`, the air's
velocity at the UAV as logged (`wind`, m/s in W, at the supervisor's rate), and wind.png."""

import matplotlib.pyplot as plt
import numpy as np

from diagrams.landing_plots import shade_modes
from diagrams.outputs import save_figure
from systems.environment.wind import WindConfig


def wind_metrics(log: dict[str, np.ndarray], config: WindConfig) -> dict:
    """The wind as configured and as the UAV met it: mean and standard deviation per W axis, and the
    largest speed (m/s)."""
    air = log["wind"]
    return {"mean_m_s": config.mean_m_s, "direction_deg": config.direction_deg, "turbulence": config.turbulence,
            "gusts": len(config.gusts),
            "at_uav": {"mean_W_m_s": air.mean(axis=0).tolist(), "std_W_m_s": air.std(axis=0).tolist(),
                       "max_speed_m_s": float(np.linalg.norm(air, axis=1).max())}}


def plot_wind(log: dict[str, np.ndarray], out_dir) -> None:
    """wind.png: the air's velocity at the UAV, per W axis, with the supervisor's modes shaded."""
    fig, ax = plt.subplots(figsize=(8, 3.5))
    shade_modes(ax, log)
    for i, (axis, colour) in enumerate(zip("xyz", ("tab:red", "tab:green", "tab:blue"))):
        ax.plot(log["t"], log["wind"][:, i], color=colour, lw=1, label=f"wind {axis}")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("air velocity in W [m/s]")
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(True, alpha=0.3)
    save_figure(fig, out_dir / "wind.png")
