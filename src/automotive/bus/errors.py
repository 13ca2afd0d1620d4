"""The one error type that the application layer turns into a single line on stderr and a non-zero exit."""


class ConfigError(Exception):
    """Bad input from a user: a properties file, a command-line value, a QoS profile name, a data file.

    The message names the file, key or value and says what was expected; it is shown as is, without traceback.
    """
