"""magtune_bag: rclpy recorder and player for rosbag2-compatible MCAP bags.

The file format itself lives in ``magtune_core.bag`` (pure Python, no rclpy); these nodes only
move serialized CDR bytes between DDS and that library.
"""
