"""Process and measurement models from the seed papers (no ROS imports)."""
