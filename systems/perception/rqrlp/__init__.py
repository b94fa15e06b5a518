"""Seed 001's RQRLP and its three vision nodes: the pattern (pattern.py), homographies and poses
(homography.py, Eq. 1-3), the nodes as functions of a frame (nodes.py), what they tell the filter
(measurements.py) and the nodes as Drake systems (node_systems.py)."""
