"""Motor hardware layer (no ROS): GRBL 1.1 protocol, its client and a simulated controller."""
