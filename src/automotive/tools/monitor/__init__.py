"""``automotive monitor``: who talks to whom on a domain, and why a writer and a reader do not match.

- :mod:`.monitor`: the command: its command line, the text report (``--once``) and the page's loop;
- :mod:`.rules`: the DDS request-offered (RxO) rules as a table, each rule a small function with its words, and the
  hints this project learned; pure Python, no DDS.
- :mod:`.model`: the snapshot of a domain (participants, topics, endpoints, matches, mismatches with their reasons,
  flows, the programs' health) built from discovery records and /diagnostics reports; :meth:`.model.Snapshot.to_json`
  is what a page renders; no DDS either.
- :mod:`.text`: the snapshot as text (``automotive monitor --once``).
- :mod:`.discovery`: the DDS side: Cyclone's built-in discovery readers and the rt/diagnostics reader, turned into the
  model's records.
- :mod:`.probes`: the monitor's own best-effort readers of the system's flows (rates, the camera's frames, the LiDAR's
  picture).
- :mod:`.server`: the page's server (aiohttp: HTTP and a WebSocket); the page's files are package data in ``page/``.
"""
