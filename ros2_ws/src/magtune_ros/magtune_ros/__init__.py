"""magtune_ros: ROS 2 Jazzy nodes of magtune (see README.md of this package)."""
