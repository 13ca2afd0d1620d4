"""``automotive launch``: start the applications together, watch them, stop them; ``launch stop``, ``launch status``
(:mod:`.launch`)."""
