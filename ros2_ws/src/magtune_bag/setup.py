"""ament_python package: recorder and player nodes (ros2 run magtune_bag recorder|player)."""
from setuptools import setup

package_name = "magtune_bag"

setup(
    name=package_name,
    version="0.1.0",
    packages=[package_name],
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="magtune",
    maintainer_email="magtune@example.com",
    description="Recorder and player nodes writing/reading rosbag2-compatible MCAP bags",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "recorder = magtune_bag.recorder:main",
            "player = magtune_bag.player:main",
        ],
    },
)
