"""Thin command-line entry points over :mod:`sfs_ros.core`."""
