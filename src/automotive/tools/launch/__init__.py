"""``automotive launch``: start the applications together, watch them, stop them; ``launch stop``, ``launch status``.

- :mod:`.launch`: the command line (its parser and ``main``), apart from the work;
- :mod:`.plan`: what to start: the applications chosen, each with its arguments, checked before any starts;
- :mod:`.supervisor`: the supervisor that starts, watches and stops them;
- :mod:`.display`: what the user sees: the console, and the modes (windows, tmux, background);
- :mod:`.registry`: how a running launcher is found (its pid file, the user's runtime folder), and ``stop``/``status``.
"""
