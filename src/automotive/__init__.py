"""Shared runtime of the automotive databus: properties, QoS profiles, network set-up, endpoints, run loop.

The idlc-generated data types live in the subpackage ``automotive.types`` (never edited by hand).
"""
