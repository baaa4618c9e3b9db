"""magtune_core: H-infinity tuning of projection-based magnetorquer attitude controllers.

Pure Python (numpy/scipy, no ROS). Implements Zanchettin & Lovera, IFAC 2011; see SPEC.md
reading in README.md. Modules: field, params, model, dynamics, periodic, tuner, gains, cli.
"""
__version__ = "0.1.0"
