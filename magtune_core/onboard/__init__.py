"""The on-board flight software: what a satellite's flight computer runs, and nothing else.

The projection law (paper eq. 17) and its state (eq. 14), B-dot detumbling and its derivative
filter, the mode machine and its compiled twin, the coarse attitude fix (TRIAD, Davenport), the
MEKF and its compiled kernel, the per-sample estimator with its on-board reference models, the
torquers' duty cycle, and the schemas of the flight nodes' parameters. Imports
:mod:`magtune_core.base` and :mod:`magtune_core.env` (the on-board Earth models) only: never the
design problem, the simulation, studies, runners or the CLI (tests/test_architecture.py).
"""
