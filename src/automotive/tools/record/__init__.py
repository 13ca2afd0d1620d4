"""``automotive record`` and ``automotive replay``: the bus to an MCAP file, and a recording back onto the bus.

- :mod:`.record`: the recorder (``automotive record``; ``--recover`` through :mod:`.mcap_recover`);
- :mod:`.replay`: the replayer (``automotive replay``);
- :mod:`.mcap_recover`: a readable copy of a killed recorder's file.

Both take the system's flows from automotive.tools.flows, which the bridges and the monitor share.
"""
