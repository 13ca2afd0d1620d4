"""Tools around the system: the launcher, recorder, replayer, Foxglove bridge, point-cloud viewer, Shapes Demo, the
configuration export, the scene-data generator, and their helpers (flows, cloudview, children).
"""
