"""The satellite design problem (paper sections 3-4): parameters, field models, the LTP attitude
model, J / c1 / c2 / rho, the LQ start, the tuners, gains files, the field fit, the simulated
sensors and injected faults. Imports :mod:`magtune_core.onboard` (the flight law it tunes),
:mod:`magtune_core.ltp`, :mod:`magtune_core.env` and :mod:`magtune_core.base` only; no simulation,
no bags, no ROS.
"""
