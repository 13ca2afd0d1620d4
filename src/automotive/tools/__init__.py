"""Tools around the system: one room (subpackage) per command a user runs, named as the command is.

- :mod:`.launch`: ``automotive launch`` (start, watch and stop the applications; ``launch stop``, ``launch status``);
- :mod:`.record`: ``automotive record`` and ``automotive replay`` (and ``record --recover``);
- :mod:`.foxglove_bridge`: ``automotive foxglove-bridge``;
- :mod:`.zenoh`: ``automotive zenoh-bridge`` and ``automotive zenoh-certs``;
- :mod:`.shapes`: ``automotive shapes-demo`` and ``automotive shape-main``;
- :mod:`.lidar_view`: ``automotive lidar-view``;
- :mod:`.monitor`: ``automotive monitor``, its model of a domain and its page;
- :mod:`.config`: ``automotive config``.

Each room holds its command's module (named as its program: ``record/record.py``, ``zenoh/zenoh_bridge.py``) and the
modules only that command uses; no room imports another's (an import-linter contract, pyproject.toml). What several
commands use lives beside the rooms, named for what it is:

- :mod:`.flows`: the system's data flows (topics, types, QoS, schemas) and their input from DDS and shared memory:
  the recorder, the replayer, the Foxglove and Zenoh bridges and the monitor;
- :mod:`.cloudview`: the picture of a point cloud: the LiDAR view and the monitor's page;
- :mod:`.support`: helpers that are no user's command (the process supervisor, the network lab, the lossy-link
  relay, the scene-data maker), used by the launcher, the benchmarks and the tests.
"""
