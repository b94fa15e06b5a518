"""Seed 001's federated EKF (Sec. 4.2): one IMU-driven local filter per vision node
(local_filter.py, Eq. 4-5), fused with Eq. 7-8, Eq. 9's dynamic beta and the information-sharing
reset of Eq. 6 (fusion.py); `step` (engine.py) is the whole filter as a pure function, and
`FederatedFilterSystem` (system.py) steps it in a Drake diagram."""
