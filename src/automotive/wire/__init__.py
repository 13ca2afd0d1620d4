"""Data on the wire: raw (serialized) samples, camera frames, the PointCloud2 codec and same-host shared memory."""
