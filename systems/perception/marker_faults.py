"""Faults in the marker measurement stream (issue 10; ours, not the papers'): the camera covered
(fixed intervals, or bursts at random times), whole frames dropped, and outliers (a measurement
replaced by a wrong pose), each drawn from the seeded noise of systems/noise.py as a pure function
of the sample index k (t_k = k T, T the stream's period), so runs repeat bit for bit.

- Occlusion: every sample inside a fixed [start, end] interval, or within `occlusion_duration_s`
  after a random burst's start; each sample starts a burst with probability rate T (a Bernoulli
  approximation of a Poisson process of `occlusion_rate_hz`; rate T at most 1, `check_period`), so
  a sample is covered with probability 1 - (1 - rate T)^n, n = ceil(duration / T).
- Drops: a frame's measurements all lost with `drop_probability`.
- Outliers: each remaining measurement, with `outlier_probability`, moved by a normal error of
  `outlier_position_m` per axis (m, in the camera frame) and turned by a normal angle of
  `outlier_deg` about a random axis.
The filters see a covered or dropped frame as a frame without markers, and must gate the outliers.
"""

import math
from dataclasses import dataclass, field, replace

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem
from scipy.spatial.transform import Rotation

from systems.config import require, require_non_negative, require_positive
from systems.noise import sample_index, sample_rng
from systems.perception.markers import MarkerMeasurement
from systems.stepped import in_intervals


@dataclass
class FaultsConfig:
    """The `faults` section (module docstring): times in s, probabilities per sample."""

    occlusions_s: list[list[float]] = field(default_factory=list)  # [start, end] intervals, camera covered
    occlusion_rate_hz: float = 0.0  # random bursts' starts per second
    occlusion_duration_s: float = 0.5  # each random burst's length
    drop_probability: float = 0.0
    outlier_probability: float = 0.0
    outlier_position_m: float = 0.5
    outlier_deg: float = 20.0

    def validate(self, prefix: str = "faults") -> None:
        """Checks every field."""
        for i, interval in enumerate(self.occlusions_s):
            require(len(interval) == 2 and 0 <= interval[0] < interval[1],
                    f"{prefix}.occlusions_s[{i}] must be [start, end] with 0 <= start < end, got {interval}")
        require_non_negative(self.occlusion_rate_hz, f"{prefix}.occlusion_rate_hz")
        for name in ("occlusion_duration_s", "outlier_position_m", "outlier_deg"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        for name in ("drop_probability", "outlier_probability"):
            require(0 <= getattr(self, name) <= 1, f"{prefix}.{name} must be within [0, 1], got {getattr(self, name)}")

    def check_period(self, period_s: float, prefix: str = "faults") -> None:
        """That a burst's start probability per sample of the stream's period `period_s` [s] is at most 1."""
        require(self.occlusion_rate_hz * period_s <= 1,
                f"{prefix}.occlusion_rate_hz ({self.occlusion_rate_hz:g}) times the stream's period ({period_s:g} s) "
                f"must be at most 1: it is a burst's start probability per sample")

    def check_within(self, duration_s: float, prefix: str = "faults") -> None:
        """That no occlusion is longer than a run of `duration_s` [s]."""
        longest = max([end - start for start, end in self.occlusions_s] +
                      [self.occlusion_duration_s if self.occlusion_rate_hz else 0.0])
        require(longest <= duration_s, f"{prefix}: an occlusion of {longest:g} s is longer than the run "
                                       f"({duration_s:g} s)")

    @property
    def active(self) -> bool:
        return bool(self.occlusions_s or self.occlusion_rate_hz or self.drop_probability or self.outlier_probability)


def occluded(k: int, period_s: float, config: FaultsConfig, seed: int) -> bool:
    """Whether sample k is covered (module docstring)."""
    if in_intervals(k * period_s, config.occlusions_s):
        return True
    if not config.occlusion_rate_hz:
        return False
    p = config.occlusion_rate_hz * period_s
    n = math.ceil(config.occlusion_duration_s / period_s - 1e-9)
    return any(sample_rng(seed, "occlusion", j).random() < p for j in range(max(k - n + 1, 0), k + 1))


def outlier(measurement: MarkerMeasurement, config: FaultsConfig, rng: np.random.Generator) -> MarkerMeasurement:
    """The measurement moved and turned by the outlier errors (module docstring); one without a finite,
    non-zero quaternion is left as it is, for the filters' screening to reject."""
    if not math.isfinite(measurement.quaternion_norm) or measurement.quaternion_norm == 0:
        return measurement
    axis = rng.normal(size=3)
    turn = Rotation.from_rotvec(axis / np.linalg.norm(axis) * math.radians(rng.normal(0.0, config.outlier_deg)))
    q_CM = (turn * Rotation.from_quat(measurement.q_CM)).as_quat()  # scalar-last, the paper's order
    return replace(measurement, p_CM=measurement.p_CM + rng.normal(0.0, config.outlier_position_m, 3), q_CM=q_CM)


def apply_faults(measurements: list, k: int, period_s: float, config: FaultsConfig, seed: int) -> list:
    """Sample k's measurements as the faults leave them."""
    if occluded(k, period_s, config, seed):
        return []
    rng = sample_rng(seed, "faults", k)
    if rng.random() < config.drop_probability:
        return []
    return [outlier(m, config, rng) if rng.random() < config.outlier_probability else m for m in measurements]


class MarkerFaults(LeafSystem):
    """Input `measurements` (a list of MarkerMeasurement, the stream as acquired); output
    `measurements` (the list with the faults applied at the sample of the context's time, t_k = k
    `period_s`). Stateless: evaluate it at the stream's samples, as its consumers do."""

    def __init__(self, config: FaultsConfig, period_s: float, seed: int = 0):
        super().__init__()
        config.validate()
        config.check_period(period_s)
        self._config, self._period, self._seed = config, period_s, seed
        self._input = self.DeclareAbstractInputPort("measurements", AbstractValue.Make([]))
        self.DeclareAbstractOutputPort("measurements", lambda: AbstractValue.Make([]), self._calc)

    def _calc(self, context, output):
        k = sample_index(context.get_time(), self._period)
        output.set_value(apply_faults(list(self._input.Eval(context)), k, self._period, self._config, self._seed))
