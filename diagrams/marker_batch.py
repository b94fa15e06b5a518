"""The open-loop marker campaign's fast path: the Diagram's numbers without a flight per run.

In gv-marker-ekf the truth steers and the filters only watch, so the flight does not depend on the
measurements. A campaign worker flies each setting once (`flight_samples`, kept in the process,
keyed by the scenario without its seed and estimation settings), and each run then replays it at the
filter steps through the functions the Diagram's systems call: the seeded noise of each sample
(`draw_noise` from `sample_rng`) applied by `noisy_marker_poses` to the true marker poses (here
computed for all samples at once), the latency queue (`delay_queue`) and the filters' `step`, with the
camera of every sample computed at once (`MarkerFilter.camera` on stacks) and every sample's estimate
vector made at the end from the filters' `record`s (`estimate_vectors`, the vector `estimate_vector`
gives at each step). tests/test_marker_batch.py checks both give the same estimates to 1e-9 on the same
seed. Only where `batch_applies`: everything else flies the Diagram.
"""

import dataclasses
import time

import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from diagrams.gv_landing import add_gv_landing
from diagrams.gv_landing_config import GvLandingConfig
from diagrams.marker_metrics import SampledRun, pad_truth, true_marker_poses_C
from diagrams.simulate import simulate
from systems.config import require
from systems.estimators.marker_ekf import FILTERS, Camera, MarkerFilter
from systems.estimators.marker_ekf.engine import EST_VALID, ESTIMATE_VECTOR_SIZE
from systems.estimators.marker_ekf.stack import run_stack
from systems.noise import sample_index, sample_rng
from systems.perception.latency import delay_queue
from systems.perception.markers import MarkerMeasurement
from systems.perception.synthetic_markers import STREAM, draw_noise, noisy_marker_poses
from systems.quaternion import drake_to_paper

_FLIGHTS: dict[str, tuple] = {}
_FLIGHTS_KEPT = 4


def batch_applies(config: GvLandingConfig) -> bool:
    """Whether the batch path gives the Diagram's numbers for `config`: the truth steers
    (perception.source truth), the stream is the paper's synthetic one without faults, the filters
    place the pad from the true UAV pose (navigation.source truth), and no seed alters the flight (no
    wind turbulence, no vehicle broadcast; a mean wind and gusts are not drawn, and other vehicles,
    drawn from the seed, are only rendered, and such a scene has no camera). Then one flight serves
    every seed."""
    return (config.perception.source == "truth" and config.estimation.source == "synthetic"
            and not config.faults.active and config.navigation.source == "truth"
            and config.wind.turbulence == "none" and config.rendezvous.source == "none")


def flight_config(config: GvLandingConfig) -> GvLandingConfig:
    """The flight alone: the scenario as a plain GvLandingConfig without its measurement stream."""
    plain = GvLandingConfig(**{f.name: getattr(config, f.name) for f in dataclasses.fields(GvLandingConfig)})
    return dataclasses.replace(plain, estimation=dataclasses.replace(config.estimation, source="none", filters=[]))


def flight_samples(config: GvLandingConfig, duration_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, quadrotor states (N, 17), vehicle states (N, 4)) at the filter steps of the flight,
    flown once per settings in this process (with seed 0: under `batch_applies` every seed flies it)."""
    require(batch_applies(config), "the batch path replays one flight for every seed: it needs perception.source "
            "truth, estimation.source synthetic, no faults, navigation.source truth, wind.turbulence none and "
            "rendezvous.source none")
    flight = dataclasses.replace(flight_config(config), seed=0)
    key = repr((dataclasses.asdict(flight), duration_s))
    if key not in _FLIGHTS:
        builder = DiagramBuilder()
        handles = add_gv_landing(builder, flight)
        period = config.estimation.ekf.period_s
        quad = LogVectorOutput(handles.quadrotor.GetOutputPort("state"), builder, period)
        vehicle = LogVectorOutput(handles.vehicle.GetOutputPort("state"), builder, period)
        diagram = builder.Build()
        context = simulate(diagram, duration_s, initialize=handles.initialize).context
        quad_log, vehicle_log = quad.FindLog(context), vehicle.FindLog(context)
        if len(_FLIGHTS) >= _FLIGHTS_KEPT:
            _FLIGHTS.pop(next(iter(_FLIGHTS)))
        _FLIGHTS[key] = (quad_log.sample_times().copy(), quad_log.data().T.copy(), vehicle_log.data().T.copy())
    return _FLIGHTS[key]


def batch_run(config: GvLandingConfig, duration_s: float) -> SampledRun:
    """The sampled run the Diagram would give for `config` (its seed) over `duration_s`."""
    t, quad, vehicle, truth, q_BR = _flight(config, duration_s)
    est, layout = config.estimation, config.platform.markers
    p_CM, q_CM = _stream(config, t, truth, config.seed)
    filters = {name: FILTERS[name](layout, est.X_BC, est.ekf) for name in config.filter_names}
    cameras = next(iter(filters.values())).camera(truth.p_WB, q_BR)  # every filter's camera is at est.X_BC
    records = {name: [None] * len(t) for name in filters}
    queue = ()
    for k, t_k in enumerate(t.tolist()):
        acquired = [MarkerMeasurement(t_k, marker_id, p, q) for marker_id, p, q in zip(layout.ids, p_CM[k], q_CM[k])]
        queue, arrived = delay_queue(queue, acquired, est.latency_periods)
        camera = Camera(*(part[k] for part in cameras))
        for name, f in filters.items():
            f.step(t_k, None, arrived, camera)
            records[name][k] = f.record()
    estimates, p_WM = {}, {}
    for name, f in filters.items():
        estimates[name], p_WM[name] = estimate_vectors(f, records[name])
    return SampledRun(t, quad, vehicle, np.concatenate([p_CM, q_CM], axis=-1), estimates, p_WM,
                      {name: dataclasses.asdict(f.stats) for name, f in filters.items()},
                      {name: f.compute_s for name, f in filters.items()})


def batch_runs(config: GvLandingConfig, seeds: list[int], duration_s: float) -> list[SampledRun]:
    """`batch_run` of `config` with each of `seeds`, the filters of every run stepped together
    (systems/estimators/marker_ekf/stack.py); the same runs to 1e-9 (tests/test_marker_stack.py).
    Each run's compute_s is its share of the filters' time."""
    t, quad, vehicle, truth, q_BR = _flight(config, duration_s)
    est, layout = config.estimation, config.platform.markers
    streams = [_stream(config, t, truth, seed) for seed in seeds]
    p_CM, q_CM = (np.array(part) for part in zip(*streams))
    estimates, p_WM, stats, compute_s = {}, {}, {}, {}
    for name in config.filter_names:
        f = FILTERS[name](layout, est.X_BC, est.ekf)
        start = time.perf_counter()
        stack = run_stack(f, t, f.camera(truth.p_WB, q_BR), p_CM, q_CM, est.latency_periods)
        compute_s[name] = (time.perf_counter() - start) / len(seeds)
        on = stack.started
        vectors = [_vectors(f, on, x[on], v[on], last[on])
                   for x, v, last in zip(stack.x, stack.position_variance, stack.last_measurement_s)]
        estimates[name], p_WM[name] = zip(*vectors)
        stats[name] = stack.stats
    return [SampledRun(t, quad, vehicle, np.concatenate([p_CM[i], q_CM[i]], axis=-1),
                       {name: estimates[name][i] for name in estimates}, {name: p_WM[name][i] for name in p_WM},
                       {name: dataclasses.asdict(stats[name][i]) for name in stats}, dict(compute_s))
            for i in range(len(seeds))]


def _flight(config: GvLandingConfig, duration_s: float):
    """(t, quadrotor states, vehicle states, `pad_truth`, the UAV's attitude q^{B/R} (N, 4), the
    paper's way, for the filters' camera) of the flight the batch path replays."""
    t, quad, vehicle = flight_samples(config, duration_s)
    truth = pad_truth(quad, vehicle, config.platform)
    return t, quad, vehicle, truth, drake_to_paper(truth.q_WB)


def _stream(config: GvLandingConfig, t: np.ndarray, truth, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The measured (p_CM (N, n, 3) [m], q^{M/C} (N, n, 4)) of run `seed`: every sample's true marker
    poses at once, each sample's noise from its own generator."""
    est, layout = config.estimation, config.platform.markers
    p_true, q_CP = true_marker_poses_C(truth, layout, est.X_BC)
    noise = [draw_noise(sample_rng(seed, STREAM, sample_index(t_k, est.ekf.period_s)), len(layout.ids),
                        est.sigma_p_m, est.sigma_deg) for t_k in t.tolist()]
    return noisy_marker_poses(p_true, drake_to_paper(q_CP), *(np.array(part) for part in zip(*noise)))


def estimate_vectors(marker_filter: MarkerFilter, records: list) -> tuple[np.ndarray, np.ndarray]:
    """(estimate vectors (N, ESTIMATE_VECTOR_SIZE), p_WM (N, n, 3)) of the filter's `record` at N steps:
    what `estimate_vector` gave at each (NaN, not valid, before the start)."""
    started = np.array([r is not None for r in records], dtype=bool)
    if not started.any():
        return _vectors(marker_filter, started, None, None, None)
    x, variance, last = (np.array(part) for part in zip(*(r for r in records if r is not None)))
    return _vectors(marker_filter, started, x, variance, last)


def _vectors(marker_filter: MarkerFilter, started: np.ndarray, x, variance, last) -> tuple[np.ndarray, np.ndarray]:
    """`estimate_vectors` at N steps, `started` (N,) of them with states x, position variances and newest
    measurement times (`MarkerFilter.record`'s)."""
    vectors = np.full((len(started), ESTIMATE_VECTOR_SIZE), np.nan)
    vectors[:, EST_VALID] = 0.0
    p_WM = np.full((len(started), len(marker_filter.p_PM), 3), np.nan)
    if started.any():
        vectors[started], p_WM[started], _ = marker_filter.estimate_vectors(x, variance, last)
    return vectors, p_WM
