"""Simulated sources: the LiDAR scene, the camera's LFSR test pattern and the CSV data of vision and platform."""
