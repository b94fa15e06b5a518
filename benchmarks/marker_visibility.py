"""Issue 10, part 1: which pad markers the downward camera detects, against the camera's height above
the pad, the UAV's tilt and its offset from the pad's centre, on rendered frames (the gv scene's
camera with its pixel noise, ArUco and solvePnP as the marker stream runs them;
diagrams/marker_visibility.py), for the default five-marker layout (marker-landing) and the nested
one of marker-landing-wind (four 6 cm markers 0.2 m out on the pad's axes).

    .venv/bin/python benchmarks/marker_visibility.py [--json FILE]

Poses: camera heights 0.3-10 m; roll 0, 5, 10, 15 deg; the body over the pad's centre and 0.05, 0.10
and 0.15 m off it in 8 directions (25 offsets); heading the pad's. Printed: the share of poses with
at least one marker detected (a marker detected is whole in the view), per height and tilt, and
each marker's detection rate per height over all tilts and offsets. Target: a marker at every pose
from the acquisition height (10 m) down to 0.3 m.
"""

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from diagrams.marker_visibility import VisibilityRig  # noqa: E402
from diagrams.outputs import output_file, write_json  # noqa: E402
from diagrams.runner import load_scenario  # noqa: E402

HEIGHTS_M = (0.3, 0.4, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 5.0, 7.5, 10.0)
TILTS_DEG = (0.0, 5.0, 10.0, 15.0)
OFFSETS_M = [(0.0, 0.0)] + [(r * np.cos(a), r * np.sin(a)) for r in (0.05, 0.10, 0.15)
                            for a in np.radians(np.arange(0, 360, 45))]
LAYOUTS = {"five (marker-landing)": "marker-landing", "nested nine (marker-landing-wind)": "marker-landing-wind"}


def visibility(scenario: str) -> dict:
    """Detections per (height, tilt): a list of id sets, one per offset; and the layout's ids."""
    _, config = load_scenario(scenario)
    rig = VisibilityRig(config)
    seen = {(h, t): [rig.detected(h, offset, t) for offset in OFFSETS_M] for h in HEIGHTS_M for t in TILTS_DEG}
    return {"ids": list(config.platform.markers.ids), "sizes_m": list(config.platform.markers.sizes_m), "seen": seen}


def report(name: str, result: dict) -> dict:
    seen, ids = result["seen"], result["ids"]
    any_rate = {(h, t): float(np.mean([bool(s) for s in seen[h, t]])) for h, t in seen}
    print(f"\n## {name}: markers {ids}, sizes {result['sizes_m']} m\n")
    print("Poses with a marker detected (25 offsets each):\n")
    print("| camera height (m) | " + " | ".join(f"roll {t:g} deg" for t in TILTS_DEG) + " |")
    print("|---|" + "---|" * len(TILTS_DEG))
    for h in HEIGHTS_M:
        print(f"| {h:g} | " + " | ".join(f"{any_rate[h, t]:.0%}" for t in TILTS_DEG) + " |")
    per_marker = {h: {i: float(np.mean([i in s for t in TILTS_DEG for s in seen[h, t]])) for i in ids}
                  for h in HEIGHTS_M}
    print("\nEach marker's detection rate over all tilts and offsets:\n")
    print("| camera height (m) | " + " | ".join(f"id {i}" for i in ids) + " |")
    print("|---|" + "---|" * len(ids))
    for h in HEIGHTS_M:
        print(f"| {h:g} | " + " | ".join(f"{per_marker[h][i]:.0%}" for i in ids) + " |")
    worst = min(any_rate.values())
    print(f"\n{'PASS' if worst == 1.0 else 'FAIL'}: a marker at every pose from 10 m down to 0.3 m "
          f"(lowest share {worst:.0%})")
    return {"any": {f"{h:g} m, {t:g} deg": r for (h, t), r in any_rate.items()},
            "per_marker": {f"{h:g} m": {str(i): r for i, r in rates.items()} for h, rates in per_marker.items()}}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=output_file, help="write the figures here too")
    args = parser.parse_args()
    out = {name: report(name, visibility(scenario)) for name, scenario in LAYOUTS.items()}
    if args.json:
        write_json(args.json, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
