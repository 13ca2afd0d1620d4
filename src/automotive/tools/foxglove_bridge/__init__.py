"""``automotive foxglove-bridge``: the live bus served to Foxglove over WebSocket.

- :mod:`.bridge`: the command: the system's flows (automotive.tools.flows) to the Foxglove SDK's server;
- :mod:`.wsrelay`: the TCP front that also accepts the protocol's older subprotocol name.
"""
