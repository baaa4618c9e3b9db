"""Runners of the ROS 2 nodes, as subprocesses: the SIL (``sil``) and the bag player
(``replay``). No rclpy import here: the nodes live in ``ros2_ws/src/magtune_ros``, found
through :mod:`magtune_core.base.ament`.
"""
