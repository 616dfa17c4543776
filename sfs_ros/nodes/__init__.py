"""ROS 2 nodes of the cell (one module per executable, each with a thin ``main()``)."""
