"""``automotive lidar-view``: the LiDAR's point cloud in a window, as log lines, or as a PNG (:mod:`.lidar_view`).

The picture itself is automotive.tools.cloudview, which the monitor's page shows too.
"""
