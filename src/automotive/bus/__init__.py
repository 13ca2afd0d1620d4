"""The databus runtime: an application's command line, properties, QoS profiles, network, participant and endpoints,
status events and records, ownership, run loop and clean shutdown. Above automotive.cyclone; below everything else.
"""
