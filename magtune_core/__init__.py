"""magtune_core: H-infinity tuning of projection-based magnetorquer attitude controllers.

Pure Python (numpy/scipy, no ROS). Implements Zanchettin & Lovera, IFAC 2011; ``docs/paper.md`` maps
each equation to its code and ``docs/architecture.md`` draws the layers. Bottom to top:

* ``ltp``     general linear time-periodic analysis (no satellite);
* ``base``    errors, parameter files and schema, rotations, topic table, ament lookup;
* ``env``     space-environment physics (orbit, IGRF, Sun, atmosphere, torques);
* ``onboard`` the flight software: law, B-dot, modes, attitude fix, MEKF, estimator, torquers;
* ``design``  the satellite design problem, tuner, gains, field fit, simulated sensors, faults;
* ``sim``     nonlinear dynamics, full-environment coupling, offline closed loop, metrics;
* ``bags``    rosbag2-compatible MCAP bags;
* ``ros``     runners of the ROS 2 nodes as subprocesses (no rclpy);
* ``studies`` sampling study, bag report;
* ``cli``     the ``magtune`` command.

Each layer imports only from layers below it (tests/test_architecture.py checks it).
"""
__version__ = "0.3.0"
