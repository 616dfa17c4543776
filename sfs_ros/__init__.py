"""sfs_ros: a turntable + C-arm camera cell that reconstructs 3-D shape from silhouettes."""
