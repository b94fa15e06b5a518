"""Statistics over the finished runs of a campaign: summary.json's "filters" section when a
campaign definition gives no aggregation of its own."""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence

import numpy as np

from diagrams.montecarlo.records import RunRecord


def _stats(values: np.ndarray) -> dict:
    """n, mean, std (the runs' own spread: ddof 0), rms and min and max over axis 0 of the values that are not
    NaN (elementwise for vectors, each element with its own n); NaN where there are none (null in summary.json)."""
    def out(x):
        return x.tolist() if isinstance(x, np.ndarray) else x.item()

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an element no run has: "Mean of empty slice", ...
        return {"n": out((~np.isnan(values)).sum(axis=0)), "mean": out(np.nanmean(values, axis=0)),
                "std": out(np.nanstd(values, axis=0)), "rms": out(np.sqrt(np.nanmean(values**2, axis=0))),
                "min": out(np.nanmin(values, axis=0)), "max": out(np.nanmax(values, axis=0))}


def _numeric_leaves(data, prefix: str = ""):
    """(dotted name, value) of every number, bool and flat list of numbers in nested dicts; a NaN number is
    left out, and a list's null elements (a run record's NaN) are NaN."""
    for key, value in data.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            yield from _numeric_leaves(value, f"{name}.")
        elif isinstance(value, (bool, int, float)) and not (isinstance(value, float) and math.isnan(value)):
            yield name, float(value)
        elif (isinstance(value, list) and value and all(v is None or isinstance(v, (bool, int, float)) for v in value)
              and any(v is not None for v in value)):
            yield name, tuple(math.nan if v is None else float(v) for v in value)


def aggregate_fields(metrics: Sequence[dict]) -> dict:
    """Statistics (n, mean, std, rms, min, max) of every numeric field of the given metrics dicts,
    by dotted name, over the runs that have it (lists of numbers elementwise, when all have one
    length, each element over the runs where it is a number, not NaN or null, with its own n;
    bools as 0/1, so their mean is a fraction)."""
    columns: dict[str, list] = {}
    for m in metrics:
        for name, value in _numeric_leaves(m):
            columns.setdefault(name, []).append(value)
    out = {}
    for name, values in columns.items():
        lengths = {len(v) if isinstance(v, tuple) else 0 for v in values}
        if len(lengths) == 1:
            out[name] = _stats(np.asarray(values, dtype=float))
    return out


def default_aggregate(done: dict[str, list[RunRecord]]) -> dict:
    """summary.json's "filters" section when a campaign gives no aggregation of its own: with
    DESIGN.md's metrics shape (an "estimators" group per run), per estimator and case the
    statistics of its numeric fields; otherwise the same under the single name "metrics"."""
    filters: dict[str, dict] = {}
    for case, records in done.items():
        groups: dict[str, list[dict]] = {}
        for r in records:
            estimators = r.metrics.get("estimators")
            if isinstance(estimators, Mapping) and all(isinstance(v, Mapping) for v in estimators.values()):
                for name, values in estimators.items():
                    groups.setdefault(name, []).append(values)
            else:
                groups.setdefault("metrics", []).append(r.metrics)
        for name, metrics in groups.items():
            filters.setdefault(name, {})[case] = aggregate_fields(metrics)
    return filters
