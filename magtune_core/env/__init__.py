"""Space environment physics (no satellite design, no control): time and Earth rotation
(``earth``), J2 orbit and orbital frame (``orbit``), IGRF-14 (``igrf``), Sun and eclipse
(``sun``), Harris-Priester atmosphere (``atmosphere``), solar radiation pressure (``srp``),
the box geometry (``geometry``) and the switchable disturbance torques (``environment``).
Imports only :mod:`magtune_core.base`.
"""
