"""Helpers that are no user's command: what the launcher, the benchmarks, the tests and the maintainers use.

- :mod:`.children`: the process supervisor: child processes whose output is read line by line, waited on, measured
  and stopped; how a program of the project is started (``program_command``); a run's work folder. Used by the
  launcher (automotive.tools.launch), the benchmarks and the tests.
- :mod:`.netlab`: network namespaces, veth links and link shaping: the benchmarks (discovery, soak, zenoh) and the
  tests that need a private network.
- :mod:`.delay_relay`: a TCP relay that delays every byte (``python -m automotive.tools.support.delay_relay``): link
  delay where the kernel has no tc netem, for the Zenoh benchmark and tests.
- :mod:`.make_scene_data`: writes the shipped scene data, the vision and platform CSV files
  (``python -m automotive.tools.support.make_scene_data``): for maintainers, checked by the tests.
"""
