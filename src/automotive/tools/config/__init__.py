"""``automotive config``: the shipped configuration exported to a folder, to edit it (:mod:`.config_export`)."""
