"""magtune_core: H-infinity tuning of projection-based magnetorquer attitude controllers.

Pure Python (numpy/scipy, no ROS). Implements Zanchettin & Lovera, IFAC 2011; see the
README for the equation-to-code map. Design model: field, params, model, design. Periodic
analysis: periodic, expm, hinf, htf, h2. Tuning: tuner, gains. Simulation: dynamics, simulate,
fullenv and the environment (earth, orbit, igrf, sun, atmosphere, srp, geometry, environment,
fitfield). Runners (subprocess only): sil, sampling, replay, report, bag*. CLI: cli.
"""
__version__ = "0.1.0"
