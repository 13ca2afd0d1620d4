"""The eight applications of the system, each a module with main(argv) and a console script automotive-<name>."""
