"""ament_python package magtune_ros: thin rclpy nodes around magtune_core (physics and control)."""
from glob import glob

from setuptools import setup

package_name = "magtune_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=[package_name],
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="magtune developers",
    maintainer_email="magtune@example.com",
    description="magtune ROS 2 nodes: simulator, attitude_sensors, controller, mode_manager (lockstep SIL)",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "simulator = magtune_ros.simulator:main",
            "attitude_sensors = magtune_ros.attitude_sensors:main",
            "controller = magtune_ros.controller:main",
            "attitude_estimator = magtune_ros.attitude_estimator:main",
            "mode_manager = magtune_ros.mode_manager:main",
            "recorder = magtune_ros.recorder:main",
            "player = magtune_ros.player:main",
            "live_bridge = magtune_ros.live_bridge:main",
        ],
    },
)
