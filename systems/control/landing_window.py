"""When to commit to the final descent onto a moving deck (ours; seed 000 lands nothing, and a ship's
deck is landed on in its quiet periods).

The deck's tilt and heave are predicted from the tracked estimate (systems/estimators/deck_tracker.py:
the normal's tilt components and heave with their rates, at constant rate) to the time the UAV would
touch down: with h the height left to the touchdown height, V the landing speed, v the UAV's present
descent speed and T the time constant of its vertical velocity loop (first order, 1 / K_v,z),
    tau = h / V + T (1 - v / V),
the time a descent takes that starts at v and settles to V (the second term is its lag: at the commit,
from a hover, it is T; once at speed, nothing). Without the lag the predicted touchdown slides later
along the deck's motion while the UAV speeds up, and a committed descent on a lively deck waves off. The window is open when
the predicted tilt stays within `max_tilt_deg` over tau +- `timing_margin_s` and the heave rate within
`max_heave_rate_m_s`; a descent already committed holds while the prediction stays within the looser
`abort_tilt_deg` and twice the heave rate (the hysteresis keeps one noisy frame from aborting it), and
always within `no_return_s` of touchdown, where climbing out would take longer than landing (and where
the tag leaves the camera's view, and the deck tracker coasts on its constant-velocity prediction), but
only while the deck's estimate is valid: without one neither flag is set, there too, since the supervisor
never descends on an invalid estimate (the tracker coasts `max_coast_steps`, 1.5 s at 20 Hz, before it
turns invalid, longer than the last half metre takes).

With `prediction: autoregressive` the tilt and the heave rate come instead from the deck predictor's
output (systems/estimators/deck_predictor.py: an autoregressive model of the tracked deck's recent history,
on a grid of horizons; the input `deck_prediction`), the heave rate too at the predicted touchdown; where
its history is short it is the constant-rate prediction itself.
"""

import math
from dataclasses import dataclass, field

import numpy as np
from pydrake.systems.framework import LeafSystem

from systems.config import require, require_non_negative, require_positive
from systems.estimators.deck_predictor import (
    DeckPredictorConfig,
    constant_rate_prediction,
    prediction_size,
    sample_prediction,
)
from systems.estimators.deck_tracker import DECK_MOTION_SIZE, tilt_deg
from systems.flags import is_set

WINDOW_SAMPLES = 5  # predictions over tau +- the margin
PREDICTIONS = ("constant_rate", "autoregressive")


@dataclass
class LandingWindowConfig:
    """Thresholds (ours). 3 deg is issue 13's limit on the deck's tilt at touchdown; commit within less so
    that the prediction's error over about a second (a few tenths of a degree) leaves room."""

    max_tilt_deg: float = 2.5
    abort_tilt_deg: float = 3.0
    max_heave_rate_m_s: float = 0.1
    timing_margin_s: float = 0.3  # the touchdown's timing error: the quadrotor's response to the descent
    no_return_s: float = 1.0  # a descent this close to touchdown is not aborted
    prediction: str = "constant_rate"  # or autoregressive: the deck predictor's (module docstring)
    predictor: DeckPredictorConfig = field(default_factory=DeckPredictorConfig)  # autoregressive's settings

    def validate(self, prefix: str = "window") -> None:
        require(self.prediction in PREDICTIONS,
                f"{prefix}.prediction '{self.prediction}' is not one of: {', '.join(PREDICTIONS)}")
        self.predictor.validate(f"{prefix}.predictor")
        for name in ("max_tilt_deg", "max_heave_rate_m_s"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(self.abort_tilt_deg >= self.max_tilt_deg, f"{prefix}.abort_tilt_deg must be at least max_tilt_deg")
        require(self.timing_margin_s >= 0, f"{prefix}.timing_margin_s must not be negative")
        require(self.no_return_s >= 0, f"{prefix}.no_return_s must not be negative")


def window_flags(deck_motion: np.ndarray, time_to_touchdown_s: float, config: LandingWindowConfig,
                 prediction: np.ndarray | None = None) -> tuple[bool, bool]:
    """(open: commit now, holds: a committed descent may go on) for the deck's motion (DECK_MOTION_SIZE) and
    the time left to touchdown [s]; both False without a valid estimate. `prediction`: the deck predictor's
    output (systems/estimators/deck_predictor.py, prediction_size), used where given and valid for the tilt
    and the heave rate over tau +- the margin; None: the constant rate."""
    if not is_set(deck_motion[6]) or not math.isfinite(time_to_touchdown_s):
        return False, False
    tau = max(time_to_touchdown_s, 0.0)
    horizon = np.linspace(max(tau - config.timing_margin_s, 0.0), tau + config.timing_margin_s, WINDOW_SAMPLES)
    if prediction is not None and is_set(prediction[0]):
        predicted = sample_prediction(prediction, horizon)
    else:
        predicted = constant_rate_prediction(deck_motion, horizon)
    tilt = float(tilt_deg(predicted[:, :2]).max())
    heave_rate = float(np.abs(predicted[:, 3]).max())
    return (tilt <= config.max_tilt_deg and heave_rate <= config.max_heave_rate_m_s,
            tau <= config.no_return_s or (tilt <= config.abort_tilt_deg and heave_rate <= 2 * config.max_heave_rate_m_s))


def time_to_touchdown(height_to_go_m: float, landing_speed_m_s: float, descent_speed_m_s: float,
                      response_time_s: float) -> float:
    """tau [s] (module docstring) for the height left [m], the landing speed and the present descent speed
    [m/s, positive down; taken within 0 and the landing speed] and the velocity loop's time constant [s]."""
    v = min(max(descent_speed_m_s, 0.0), landing_speed_m_s)
    return height_to_go_m / landing_speed_m_s + response_time_s * (1.0 - v / landing_speed_m_s)


class LandingWindow(LeafSystem):
    """Inputs `deck_motion` (DECK_MOTION_SIZE), `height_above_target` (1, m: the seam's) and optionally
    `vertical_velocity` (1, the UAV's z velocity in W [m/s], from its navigation; unconnected: the
    descent's lag is left out) and `deck_prediction` (prediction_size(config.predictor), the deck predictor's;
    unconnected: the constant rate). Output `landing_window` (2: [open, holds], 1 or 0), computed when pulled,
    for the landing supervisor; the time to touchdown is `time_to_touchdown` of the height less
    `touchdown_height_m`, `landing_speed_m_s` and `response_time_s` (1 / the flight controller's K_v,z)."""

    def __init__(self, config: LandingWindowConfig, touchdown_height_m: float, landing_speed_m_s: float,
                 response_time_s: float = 0.0):
        super().__init__()
        config.validate()
        require_positive(touchdown_height_m, "landing_window touchdown_height_m")
        require_positive(landing_speed_m_s, "landing_window landing_speed_m_s")
        require_non_negative(response_time_s, "landing_window response_time_s")
        self._config, self._touchdown, self._speed = config, touchdown_height_m, landing_speed_m_s
        self._response = response_time_s
        self._motion = self.DeclareVectorInputPort("deck_motion", DECK_MOTION_SIZE)
        self._height = self.DeclareVectorInputPort("height_above_target", 1)
        self._vertical = self.DeclareVectorInputPort("vertical_velocity", 1)
        self._prediction = self.DeclareVectorInputPort("deck_prediction", prediction_size(config.predictor))
        self.DeclareVectorOutputPort("landing_window", 2, self._calc)

    def _calc(self, context, output):
        descent = -float(self._vertical.Eval(context)[0]) if self._vertical.HasValue(context) else self._speed
        tau = time_to_touchdown(float(self._height.Eval(context)[0]) - self._touchdown, self._speed, descent,
                                self._response)
        prediction = self._prediction.Eval(context) if self._prediction.HasValue(context) else None
        output.SetFromVector([float(flag) for flag in window_flags(self._motion.Eval(context), tau, self._config,
                                                                   prediction)])
