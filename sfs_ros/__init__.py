"""sfs_ros: a turntable + C-arm camera cell that reconstructs 3-D shape from silhouettes.

Importing it changes nothing in the process: each entry point sets the process up first
(:func:`sfs_ros.process.configure_process`)."""
