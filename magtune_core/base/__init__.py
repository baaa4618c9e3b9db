"""Bottom layer: what every other layer may use and that knows no satellite physics.

Errors for user files, the ROS 2 parameter-file reader and the one parameter schema
(``schema``), rotations and small vector helpers, the project's topic table, the
ament-index lookup and process pools whose workers die with their parent (``workers``).
Imports nothing else from magtune_core.
"""
