"""``automotive zenoh-bridge`` and ``automotive zenoh-certs``: chosen topics carried between two sites over Eclipse
Zenoh, and the certificates of the sites' mutual TLS.

- :mod:`.zenoh_bridge`: the site bridge (its Zenoh side is automotive.wire.zenoh_link);
- :mod:`.zenoh_certs`: the certificates of two sites (also used by the Zenoh benchmark).
"""
