"""The Shapes programs: ``automotive shapes-demo`` and ``automotive shape-main``.

- :mod:`.shapes`: a small Shapes Demo: publish a moving circle, or print the circles seen;
- :mod:`.shape_main`: the OMG interoperability suite's shape application (its moving shape is :mod:`.shapes`').
"""
