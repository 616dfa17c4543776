"""The cell's logic without ROS: scan plans, settling, live reconstruction, output paths.

The cell's ROS nodes are thin wrappers around these; nothing here imports ROS.
"""
