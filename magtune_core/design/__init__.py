"""The satellite design problem (paper sections 3-4): parameters, field models, the LTP
attitude model, J / c1 / c2 / rho, the LQ start, the tuner, gains files, the field fit and the
flight control law. Imports :mod:`magtune_core.ltp`, :mod:`magtune_core.env` and
:mod:`magtune_core.base` only; no simulation, no bags, no ROS.
"""
