"""metrics.json's `landing` and `tracking` sections of a gv flight, from the truth whatever steered.

Touchdown is the first of: the supervisor's LANDED (its estimate says the gear is down: the motors
stop, and the UAV falls the rest of the way, if any, from the state the supervisor saw), or the gear
touching the pad (the true height above the pad down to `landing.touchdown_height_m`). The touchdown
error and the relative vertical speed are those at impact.
"""

import math

import numpy as np

from diagrams.simulate import COMPLETED
from systems.control.landing import Mode
from systems.control.monitor import (
    FAILURE_REASONS,
    GEAR_TOUCHED,
    GV_HEADING,
    GV_STEERING,
    SUPERVISOR_LANDED,
    gear_on_pad,
    pad_offset,
)
from systems.perception.seam import HEIGHT, P_BP_W, V_WP
from systems.vehicles.quadrotor import V_WB

# Issue 4's targets, for the `meets_targets` flag (never a pass/fail of the run itself).
TARGET_TOUCHDOWN_ERROR_M = 0.10
TARGET_TOUCHDOWN_REL_SPEED_MPS = 0.5
SETTLED_WINDOW_S = 2.0  # the tracking error "before the final descent" is taken over this window
SETTLED_TOLERANCE_M = 0.01  # seed 003 Fig. 8: settles to about 0.01 m in x and y


def first(mask) -> int | None:
    """Index of the first True, or None."""
    index = np.flatnonzero(mask)
    return int(index[0]) if index.size else None


def entered(modes: np.ndarray, mode: Mode) -> int | None:
    """The log index at which the supervisor first decided `mode`, or None. Its mode is discrete state, so
    the logger (at its rate) shows at t_i the mode decided at t_(i-1): one sample before the first logged."""
    i = first(modes == mode)
    return None if i is None else max(i - 1, 0)


def touchdown(log: dict[str, np.ndarray], touchdown_height_m: float, pad_size_m: float, pad_thickness_m: float,
              heading: np.ndarray, status: str = "", motors_stop_at_landed: bool = True) -> tuple[int, str] | None:
    """(log index, "supervisor" or "contact") of the touchdown (module docstring), or None. `heading`: the
    pad frame's heading per sample [rad]. A contact is from above: the UAV under the pad's underside (more
    than pad_thickness_m [m] below its top) is not on it. `status`: how the run ended. A run stopped by the
    monitor on the supervisor's LANDED or on the gear's touch may miss that sample in the log (the run stops
    at the step it is declared): its last sample is then what the supervisor saw, or the touch.
    `motors_stop_at_landed` false (landing.touchdown_by contact): only the touch counts, the supervisor's
    LANDED descending on to it."""
    landed = first(log["mode"] == Mode.LANDED) if motors_stop_at_landed else None
    if landed is None and motors_stop_at_landed and status.startswith(SUPERVISOR_LANDED):
        landed = len(log["mode"])
    relative = log["true_relative_state"]
    contact = first(gear_on_pad(relative, heading, touchdown_height_m, pad_size_m, pad_thickness_m))
    if contact is None and status.startswith(GEAR_TOUCHED):
        contact = len(relative) - 1
    candidates = [(max(landed - 1, 0), 0, "supervisor")] if landed is not None else []
    candidates += [(contact, 1, "contact")] if contact is not None else []
    return min(candidates)[::2] if candidates else None


def impact(gap_m: float, vertical_speed: float, gravity: float) -> tuple[float, float]:
    """(time [s], downward speed [m/s]) of a fall of gap_m [m] starting at `vertical_speed` (the UAV's
    relative to the pad, m/s, z up) with the motors stopped: a UAV still rising goes up and falls back first."""
    if gap_m <= 0:
        return 0.0, max(-vertical_speed, 0.0)
    speed = math.sqrt(vertical_speed * vertical_speed + 2.0 * gravity * gap_m)
    return (speed + vertical_speed) / gravity, speed


def pad_arguments(heading: np.ndarray, size_m: float, thickness_m: float, landing) -> dict:
    """`touchdown`'s (and `pad_landing`'s) pad arguments: the pad's heading per sample [rad], its size and
    thickness [m], and the scenario's `landing` settings (touchdown height, motors stopped at LANDED)."""
    return {"heading": heading, "pad_size_m": size_m, "pad_thickness_m": thickness_m,
            "touchdown_height_m": landing.touchdown_height_m, "motors_stop_at_landed": landing.motors_stop_at_landed}


def _gv_pad(log: dict[str, np.ndarray], config) -> dict:
    """The pad on the ground vehicle, headed as the vehicle."""
    return pad_arguments(log["vehicle_state"][:, GV_HEADING], config.platform.pad_size_m,
                         config.platform.pad_thickness_m, config.landing)


def gv_touchdown(log: dict[str, np.ndarray], status: str, config) -> tuple[int, str] | None:
    """`touchdown` of a gv flight, as `landing_metrics` scores it."""
    return touchdown(log, status=status, **_gv_pad(log, config))


def landing_metrics(log: dict[str, np.ndarray], status: str, config) -> dict:
    """A gv flight's "landing" section: `pad_landing`'s, with the vehicle's speed and turn radius at touchdown."""
    out, k = pad_landing(log, status, gravity_m_s2=config.quadrotor.gravity_m_s2, **_gv_pad(log, config))
    if k is not None:
        steering = log["vehicle_state"][k, GV_STEERING]
        out["vehicle_speed_at_touchdown_m_s"] = float(log["vehicle_speed"][k])
        # The vehicle's turn radius (bicycle: d / tan(steering)); null on a straight (steering under 1 mrad:
        # a radius over 3.5 km).
        out["vehicle_turn_radius_at_touchdown_m"] = (float(abs(config.vehicle.wheelbase_m / np.tan(steering)))
                                                     if abs(steering) > 1e-3 else None)
    return out


def pad_landing(log: dict[str, np.ndarray], status: str, heading: np.ndarray, pad_size_m: float,
                pad_thickness_m: float, touchdown_height_m: float, gravity_m_s2: float,
                motors_stop_at_landed: bool = True) -> tuple[dict, int | None]:
    """The "landing" section of a flight onto a pad of pad_size_m [m], pad_thickness_m [m] thick, headed
    `heading` [rad] per sample (the log's `t`, `mode`, `true_relative_state` and `quadrotor_state`), and the
    log index of the touchdown (None without one): success (touched down on the pad), touchdown error and
    relative speed at impact, the failure reason, when each supervisor mode was first entered, and
    `descent_counts`."""
    kind = status.split(":", 1)[0]
    out = {"success": False, "touchdown_error_m": None, "touchdown_rel_speed_mps": None, "time_to_land_s": None,
           "failure_reason": None, "failure_detail": None}
    found = touchdown(log, touchdown_height_m, pad_size_m, pad_thickness_m, heading, status, motors_stop_at_landed)
    k = None
    if found is not None:
        k, by = found
        relative, quad = log["true_relative_state"][k], log["quadrotor_state"][k]
        v_rel = quad[V_WB] - relative[V_WP]
        gap = relative[HEIGHT] - touchdown_height_m  # the gear above the pad when the motors stop
        fall_s, speed = impact(gap, v_rel[2], gravity_m_s2)
        at_impact = relative.copy()
        at_impact[P_BP_W] = relative[P_BP_W] - fall_s * v_rel  # pad minus UAV after the fall
        offset_P = pad_offset(at_impact, heading[k])
        on_pad = bool(np.all(np.abs(offset_P) <= pad_size_m / 2))
        error = float(np.linalg.norm(at_impact[P_BP_W][:2]))
        out.update({
            "success": on_pad,
            "touchdown_error_m": error,
            "touchdown_rel_speed_mps": speed,
            "time_to_land_s": float(log["t"][k] + fall_s),
            "touchdown_by": by,  # the supervisor's LANDED, or the gear touching first
            "touchdown_gap_m": float(max(gap, 0.0)),  # fallen with the motors stopped
            "touchdown_offset_pad_xy_m": offset_P.tolist(),  # UAV centre in the pad frame
            "touchdown_rel_speed_horizontal_mps": float(np.linalg.norm(v_rel[:2])),
            "touchdown_height_m": float(relative[HEIGHT]),  # true, when the supervisor saw it
        })
        if not on_pad:
            out["failure_reason"], out["failure_detail"] = "missed_pad", (
                f"touched down {error:.2f} m from the pad centre, off the {pad_size_m:g} m pad")
    elif status == COMPLETED:
        out["failure_reason"], out["failure_detail"] = "timeout", f"no touchdown by t = {log['t'][-1]:.1f} s"
    else:
        out["failure_reason"] = kind if kind in FAILURE_REASONS else "diverged"
        out["failure_detail"] = status.split(":", 1)[1].strip() if kind in FAILURE_REASONS else status
    out["meets_targets"] = bool(out["success"] and out["touchdown_error_m"] < TARGET_TOUCHDOWN_ERROR_M
                                and out["touchdown_rel_speed_mps"] < TARGET_TOUCHDOWN_REL_SPEED_MPS)
    out["mode_entry_times_s"] = {mode.name.lower(): float(log["t"][i]) for mode in Mode
                                 if (i := entered(log["mode"], mode)) is not None}
    if out["time_to_land_s"] is not None:
        out["mode_entry_times_s"]["landed"] = out["time_to_land_s"]
    out.update(descent_counts(log["t"], log["mode"]))
    return out, k


def descent_counts(t: np.ndarray, mode: np.ndarray) -> dict:
    """How often the final descent was given up (`aborts`: into ABORT, or from LAND back to WAIT when the
    landing window closed) and begun again (`retries`), and the waits for a landing window (`waits`,
    `wait_s`: the time spent in WAIT), from the logged modes at times t [s]."""
    begins = np.r_[True, mode[1:] != mode[:-1]]  # the samples where a mode begins
    waved_off = np.r_[False, (mode[1:] == Mode.WAIT) & (mode[:-1] == Mode.LAND)]
    waiting = mode == Mode.WAIT
    return {"aborts": int(np.count_nonzero(begins & (mode == Mode.ABORT)) + np.count_nonzero(waved_off)),
            "retries": max(int(np.count_nonzero(begins & (mode == Mode.LAND))) - 1, 0),
            "waits": int(np.count_nonzero(begins & waiting)),
            "wait_s": float(np.sum(np.diff(t, append=t[-1])[waiting])) if len(t) else 0.0}


def tracking_metrics(log: dict[str, np.ndarray]) -> dict:
    """The true horizontal tracking error (pad centre minus UAV, World x and y) before the final
    descent: RMSE and largest error over APPROACH (descending while tracking; the acquisition in
    FOLLOW is left out), the error at the start of LAND and its largest value over the
    SETTLED_WINDOW_S before, and the time from the first FOLLOW after which it stays within
    SETTLED_TOLERANCE_M."""
    t, mode = log["t"], log["mode"]
    error = log["true_relative_state"][:, P_BP_W][:, :2]
    land = first(mode == Mode.LAND)
    end = land if land is not None else len(t)
    before = np.arange(len(t)) < end
    out = {}
    approach = (mode == Mode.APPROACH) & before
    if approach.any():
        e = error[approach]
        out.update({"approach_rmse_xy_m": np.sqrt(np.mean(e**2, axis=0)).tolist(),
                    "approach_max_abs_xy_m": np.abs(e).max(axis=0).tolist()})
    start = first(mode == Mode.FOLLOW)
    if start is not None and start < end:
        outside = np.flatnonzero(np.any(np.abs(error[start:end]) > SETTLED_TOLERANCE_M, axis=1))
        settled_at = start + (outside[-1] + 1 if outside.size else 0)
        out["settled_within_m"] = SETTLED_TOLERANCE_M
        out["settling_time_s"] = float(t[settled_at] - t[start]) if settled_at < end else None
    if land is not None:
        window = (t >= t[land] - SETTLED_WINDOW_S) & before
        out["at_final_descent_xy_m"] = error[entered(mode, Mode.LAND)].tolist()
        out["before_final_descent_max_abs_xy_m"] = np.abs(error[window]).max(axis=0).tolist()
        out["before_final_descent_window_s"] = SETTLED_WINDOW_S
    return out
