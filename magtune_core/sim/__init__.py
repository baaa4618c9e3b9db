"""Simulation: the nonlinear attitude model (``dynamics``), its coupling to the full space
environment (``fullenv``), the offline closed loop with the flight law (``simulate``) and the
figures of merit of a run (``metrics``). Imports design, env and base.
"""
