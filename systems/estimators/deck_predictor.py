"""The deck's tilt and heave predicted seconds ahead from their recent history (ours: seed 000 does not
predict the deck, and systems/control/landing_window.py's constant rate is a degree off over 2 s on a
lively deck).

Ship motion is narrow-band, and its classic short-term predictor is the autoregressive one (Yumori 1981,
"Real time prediction of ship response to ocean waves using time series analysis"): each channel x (the
deck tracker's n_x, n_y and heave z, systems/estimators/deck_tracker.py, sampled at the camera frames) is
modelled as
    x[i] - m = c + a_1 (x[i - L] - m) + ... + a_p (x[i - p L] - m),
p lags `order` spaced L = `lag_s` apart (the series decimated to the lag: the deck's periods are 20-40 s,
and lags a frame apart are too alike to fit through the tracker's noise), m the window's mean. The
coefficients are fitted by linear least squares (numpy.linalg.lstsq) over the last `history_s`, taking
every frame as a target (the L-decimated series at each of its L phases), refitted every `refit_s`, and
the model is iterated forward: a horizon h <= L is one step from history, a longer one steps on its own
predictions. Each channel has its own model. The heave rate at frame i (i = 0 the history's last) is the
difference across the lag,
    dz/dt[i] = (z[i + L] - z[i - L]) / (2 L T)  [m/s], T the frame period,
two frames of the same phase of the decimated series (z[i - L] the history's where i <= L). Neighbouring
frames are forecast each from its own older frames and carry unrelated noise: their one-frame difference was
ten times the constant rate's error on tests/test_deck_predictor.py's tracked deck (0.05-0.06 m/s RMS, at
worst 0.2, against the landing window's 0.1 m/s). (Tried on tests/test_deck_predictor.py's tracked deck and
not kept: a 1 s moving average of the history before the fit, ridge-regularised or forward-backward fits,
45-60 s windows, 4 or 8 lags, 0.75-2 s lag spacing: none better by more than a few hundredths of a degree,
most worse.)

With less than `min_history_s` of valid frames (20 s by default, about one period of stewart-dynamic's
motion; the fit needs its p L of lags and as many rows beyond them), a failed fit, or a forecast that is
not finite or leaves the history's range by more than its own span, the prediction falls back to the
constant-rate one:
    n(t + h) = n + h dn/dt,  z(t + h) = z + h dz/dt,  dz/dt(t + h) = dz/dt.

`DeckPredictor` (LeafSystem) keeps the history as state at the camera period and outputs the prediction
on a grid of horizons, which the landing window samples (systems/control/landing_window.py).
"""

import math
from dataclasses import dataclass, field

import numpy as np
from pydrake.systems.framework import LeafSystem

from systems.config import require, require_positive
from systems.estimators.deck_tracker import DECK_MOTION_SIZE
from systems.flags import is_set
from systems.stepped import SteppedValue

PREDICTION_STEP_S = 0.1  # the output grid's spacing: horizons 0, 0.1, ..., horizon_s
CHANNELS = 3  # n_x, n_y, z
PREDICTED = 4  # n_x, n_y, z, dz/dt


@dataclass
class DeckPredictorConfig:
    """The autoregressive predictor's settings (module docstring), in seconds; the deck-landing decks'
    periods are 20-40 s (stewart-dynamic's roll 20 s, pitch 27 s, heave 24 s)."""

    history_s: float = 30.0  # the sliding window the model is fitted over
    min_history_s: float = 20.0  # less valid history than this: constant rate
    order: int = 6  # p, the lags
    lag_s: float = 0.5  # L, their spacing
    refit_s: float = 0.25  # the model is refitted this often (every 5 frames at 20 Hz)
    horizon_s: float = 5.0  # the output grid's reach; beyond it the window extends the last two samples

    def validate(self, prefix: str = "predictor") -> None:
        for name in ("history_s", "min_history_s", "lag_s", "refit_s", "horizon_s"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(self.order >= 1, f"{prefix}.order must be at least 1, got {self.order}")
        require(self.horizon_s >= PREDICTION_STEP_S,
                f"{prefix}.horizon_s must be at least the grid's step, {PREDICTION_STEP_S:g} s, got {self.horizon_s:g}")
        require(self.min_history_s <= self.history_s,
                f"{prefix}.min_history_s ({self.min_history_s:g}) must not exceed {prefix}.history_s "
                f"({self.history_s:g})")
        lags = self.order * self.lag_s
        require(self.min_history_s >= 2 * lags,
                f"{prefix}.min_history_s ({self.min_history_s:g} s) must be at least twice order x lag_s "
                f"({lags:g} s): the fit needs as many rows beyond its lags")

    def validate_frames(self, period_s: float, prefix: str = "predictor") -> None:
        """At a camera period of period_s [s]: the history kept (history_s) holds more frames than `fit_ar`'s
        p lags and its p + 1 unknowns (else the model is never fitted, and the prediction stays at constant
        rate)."""
        lag, p = _frames(self.lag_s, period_s), self.order
        need = p * lag + p + 2
        require(_frames(self.history_s, period_s) >= need,
                f"{prefix}.history_s ({self.history_s:g} s) holds {_frames(self.history_s, period_s)} frames at "
                f"{period_s:g} s; the fit of order {p} at lag_s {self.lag_s:g} needs {need}")


def horizon_grid(config: DeckPredictorConfig) -> np.ndarray:
    """The DeckPredictor output's horizons [s]: 0 to horizon_s every PREDICTION_STEP_S."""
    return PREDICTION_STEP_S * np.arange(round(config.horizon_s / PREDICTION_STEP_S) + 1)


def prediction_size(config: DeckPredictorConfig) -> int:
    """The length of DeckPredictor's `deck_prediction` output: [valid, autoregressive, then n_x, n_y, z and
    dz/dt each over horizon_grid]."""
    return 2 + PREDICTED * len(horizon_grid(config))


@dataclass(frozen=True)
class ArModel:
    """Per channel (n_x, n_y, z): the mean m (CHANNELS,) and [c, a_1 .. a_p] (CHANNELS, p + 1)."""

    mean: np.ndarray
    coefficients: np.ndarray


def _frames(seconds: float, period_s: float) -> int:
    return max(round(seconds / period_s), 1)


def fit_ar(history: np.ndarray, config: DeckPredictorConfig, period_s: float) -> ArModel | None:
    """The least-squares AR model of the history ((N, CHANNELS), one row a frame, oldest first; the last
    history_s of it), or None when it is shorter than min_history_s or the fit is not finite."""
    history = np.asarray(history, dtype=float)[-_frames(config.history_s, period_s):]
    lag, p = _frames(config.lag_s, period_s), config.order
    if len(history) < _frames(config.min_history_s, period_s) or len(history) <= p * lag + p + 1 \
            or not np.all(np.isfinite(history)):
        return None
    mean = history.mean(axis=0)
    x = history - mean
    rows = len(x) - p * lag
    design = np.empty((rows, p + 1))
    design[:, 0] = 1.0
    coefficients = np.empty((CHANNELS, p + 1))
    for c in range(CHANNELS):
        for j in range(1, p + 1):
            design[:, j] = x[p * lag - j * lag:len(x) - j * lag, c]
        try:
            coefficients[c] = np.linalg.lstsq(design, x[p * lag:, c], rcond=None)[0]
        except np.linalg.LinAlgError:
            return None
    if not (np.all(np.isfinite(coefficients)) and np.all(np.isfinite(mean))):
        return None
    return ArModel(mean, coefficients)


def forecast_ar(series: np.ndarray, model: ArModel, config: DeckPredictorConfig, period_s: float,
                frames: int) -> np.ndarray:
    """(frames, CHANNELS): the model iterated from the series' last row, 1 .. frames frames ahead."""
    lag, p = _frames(config.lag_s, period_s), model.coefficients.shape[1] - 1
    start = p * lag
    buffer = np.empty((start + frames, CHANNELS))
    buffer[:start] = np.asarray(series, dtype=float)[-start:] - model.mean
    c, a = model.coefficients[:, 0], model.coefficients[:, 1:]
    for first in range(start, start + frames, lag):  # a block of `lag` frames needs only earlier blocks
        last = min(first + lag, start + frames)
        block = np.broadcast_to(c, (last - first, CHANNELS)).copy()
        for j in range(1, p + 1):
            block += a[:, j - 1] * buffer[first - j * lag:last - j * lag]
        buffer[first:last] = block
    return buffer[start:] + model.mean


def constant_rate_prediction(deck_motion: np.ndarray, horizons_s: np.ndarray) -> np.ndarray:
    """(len(horizons), PREDICTED): [n_x, n_y, z, dz/dt] at constant rate from the deck motion."""
    h = np.asarray(horizons_s, dtype=float)
    m = deck_motion
    return np.column_stack([m[0] + m[2] * h, m[1] + m[3] * h, m[4] + m[5] * h, np.full(len(h), m[5])])


def _plausible(forecast: np.ndarray, history: np.ndarray) -> bool:
    low, high = history.min(axis=0), history.max(axis=0)
    span = high - low
    return bool(np.all(np.isfinite(forecast)) and np.all(forecast >= low - span) and np.all(forecast <= high + span))


def forecast_trajectory(history: np.ndarray, config: DeckPredictorConfig, period_s: float, frames: int,
                        model: ArModel | None = None) -> np.ndarray | None:
    """(frames + 1, PREDICTED): [n_x, n_y, z, dz/dt] at the frames 0, 1, .., frames from the history's last
    ((N, CHANNELS) [n_x, n_y, z] at the frames, oldest first), the AR model's (`model`, or None: fitted here)
    past the history; dz/dt across the lag L (module docstring: from the history's last L frames and L
    frames forecast beyond `frames`). None where there is no model or its forecast is not plausible (module
    docstring): the constant rate's case."""
    history = np.asarray(history, dtype=float)[-_frames(config.history_s, period_s):]
    if model is None:
        model = fit_ar(history, config, period_s)
    if model is None:
        return None
    lag = _frames(config.lag_s, period_s)
    need = max((model.coefficients.shape[1] - 1) * lag, lag + 1)
    if len(history) < need or not np.all(np.isfinite(history[-need:])):
        return None
    forecast = forecast_ar(history, model, config, period_s, frames + lag)
    if not _plausible(forecast, history):
        return None
    trajectory = np.vstack([history[-lag - 1:], forecast])  # frames -L .. frames + L
    z = trajectory[:, 2]
    return np.column_stack([trajectory[lag:lag + frames + 1], (z[2 * lag:] - z[:-2 * lag]) / (2 * lag * period_s)])


def sample_trajectory(trajectory: np.ndarray, horizons_s: np.ndarray, period_s: float) -> np.ndarray:
    """(len(horizons), PREDICTED): a forecast_trajectory at `horizons_s` [s] after its frame 0, linear
    between frames."""
    times = period_s * np.arange(len(trajectory))
    return np.column_stack([np.interp(horizons_s, times, trajectory[:, c]) for c in range(PREDICTED)])


def predict_deck(history: np.ndarray, deck_motion: np.ndarray, horizons_s: np.ndarray,
                 config: DeckPredictorConfig, period_s: float,
                 model: ArModel | None = None) -> tuple[np.ndarray, bool]:
    """([n_x, n_y, z, dz/dt] (len(horizons), PREDICTED), autoregressive) `horizons_s` [s, >= 0] after the
    history's last frame, whose deck motion (DECK_MOTION_SIZE) is `deck_motion`. `history`: (N, CHANNELS)
    [n_x, n_y, z] at the frames, oldest first, the last one deck_motion's. `model`: the AR model to use
    (None: fitted here). autoregressive is False where the prediction fell back to the constant rate."""
    horizons = np.asarray(horizons_s, dtype=float)
    frames = math.ceil(float(horizons.max(initial=0.0)) / period_s)
    trajectory = forecast_trajectory(history, config, period_s, frames, model)
    if trajectory is None:
        return constant_rate_prediction(deck_motion, horizons), False
    return sample_trajectory(trajectory, horizons, period_s), True


def sample_prediction(prediction: np.ndarray, horizons_s: np.ndarray) -> np.ndarray:
    """(len(horizons), PREDICTED): the DeckPredictor output `prediction` (prediction_size) at `horizons_s`
    [s, >= 0]: linear between its grid's samples, beyond the grid along its last two (exact for the
    constant-rate fallback)."""
    grid_size = (len(prediction) - 2) // PREDICTED
    grid = PREDICTION_STEP_S * np.arange(grid_size)
    values = np.asarray(prediction[2:], dtype=float).reshape(PREDICTED, grid_size)
    h = np.asarray(horizons_s, dtype=float)
    out = np.column_stack([np.interp(h, grid, row) for row in values])
    beyond = h > grid[-1]
    if np.any(beyond):
        slope = (values[:, -1] - values[:, -2]) / PREDICTION_STEP_S
        out[beyond] = values[:, -1] + np.outer(h[beyond] - grid[-1], slope)
    return out


@dataclass(frozen=True)
class PredictorState:
    """The predictor at its last frame `time` [s] (None before the first): `history` (N, CHANNELS) of valid
    frames, oldest first (empty while the deck motion is invalid); the frame's deck motion; the AR model
    (or None), the frames since it was fitted, and the frame's forecast_trajectory (None: constant rate)."""

    time: float | None = None
    history: np.ndarray = field(default_factory=lambda: np.zeros((0, CHANNELS)))
    deck_motion: np.ndarray = field(default_factory=lambda: np.zeros(DECK_MOTION_SIZE))
    model: ArModel | None = None
    frames_since_fit: int = 0
    trajectory: np.ndarray | None = None


def _trajectory_frames(config: DeckPredictorConfig, period_s: float) -> int:
    """The frames a state's trajectory reaches: the grid's last horizon, read up to a frame late."""
    return math.ceil(horizon_grid(config)[-1] / period_s) + 1


def step_predictor(state: PredictorState, deck_motion: np.ndarray, time: float, config: DeckPredictorConfig,
                   period_s: float) -> PredictorState:
    """One camera frame: the frame's deck motion appended to the history (cleared where it is invalid), the
    model refitted every refit_s, and the forecast from the frame. A frame the tracker coasted through (no
    pose: deck_motion[7] > 0) appends the last frame's forecast of it where there is one (iterating on, as
    if unseen), not the tracker's straight line, and refits nothing."""
    deck_motion = np.array(deck_motion, dtype=float)
    if not is_set(deck_motion[6]) or not np.all(np.isfinite(deck_motion[:6])):
        return PredictorState(time, deck_motion=deck_motion)
    sample = deck_motion[[0, 1, 4]]
    coasted = deck_motion[7] > 0 and state.trajectory is not None
    if coasted:
        sample = state.trajectory[1, :CHANNELS]  # one frame ahead of the last
        deck_motion[[0, 1, 4]] = sample
    history = np.vstack([state.history, sample])[-_frames(config.history_s, period_s):]
    model, since = state.model, state.frames_since_fit + 1
    if not coasted and (model is None or since >= _frames(config.refit_s, period_s)):
        model, since = fit_ar(history, config, period_s), 0
    trajectory = None if model is None else forecast_trajectory(
        history, config, period_s, _trajectory_frames(config, period_s), model)
    return PredictorState(time, history, deck_motion, model, since, trajectory)


def predictor_output(state: PredictorState, time: float, config: DeckPredictorConfig,
                     period_s: float) -> np.ndarray:
    """DeckPredictor's output (prediction_size) at `time` [s] from its state at the last frame: the
    state's forecast (as predict_deck's with the state's model), or the constant rate."""
    out = np.zeros(prediction_size(config))
    if state.time is None or not is_set(state.deck_motion[6]):
        return out
    horizons = horizon_grid(config) + min(max(time - state.time, 0.0), period_s)
    if state.trajectory is None:
        prediction = constant_rate_prediction(state.deck_motion, horizons)
    else:
        prediction = sample_trajectory(state.trajectory, horizons, period_s)
    if not np.all(np.isfinite(prediction)):
        return out
    out[0], out[1] = 1.0, float(state.trajectory is not None)
    out[2:] = prediction.T.reshape(-1)
    return out


class DeckPredictor(LeafSystem):
    """Input `deck_motion` (DECK_MOTION_SIZE, the deck tracker's). Stepped at the camera's `period_s`
    (SteppedValue: a reader at a frame time sees that frame). Output `deck_prediction` (prediction_size:
    [valid, autoregressive (1) or constant rate (0), then n_x, n_y, z [m] and dz/dt [m/s] each over
    horizon_grid, counted from the time the output is read]); all zeros while the deck motion is invalid."""

    def __init__(self, config: DeckPredictorConfig, period_s: float):
        super().__init__()
        config.validate()
        self._config, self._period = config, period_s
        self._motion = self.DeclareVectorInputPort("deck_motion", DECK_MOTION_SIZE)
        now = SteppedValue(self, "deck_predictor", PredictorState(), period_s, self._step,
                           lambda state: state.time).now
        self.DeclareVectorOutputPort(
            "deck_prediction", prediction_size(config),
            lambda c, o: o.SetFromVector(predictor_output(now.Eval(c), c.get_time(), config, period_s)),
            {now.ticket(), self.time_ticket()})

    def _step(self, context, state: PredictorState) -> PredictorState:
        return step_predictor(state, self._motion.Eval(context), context.get_time(), self._config, self._period)

