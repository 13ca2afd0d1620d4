"""The one error type that the application layer turns into a single line on stderr and a non-zero exit."""

from collections.abc import Iterator
from contextlib import contextmanager

from cyclonedds.core import DDSException


class ConfigError(Exception):
    """Bad input from a user: a properties file, a command-line value, a QoS profile name, a data file.

    The message names the file, key or value and says what was expected; it is shown as is, without traceback.
    """


@contextmanager
def refused_as_config_error(what: str) -> Iterator[None]:
    """An entity Cyclone refuses to create for what the user configured (a topic name it does not accept, QoS
    policies that contradict each other, such as a deadline shorter than the time-based filter) is bad input: one
    line naming ``what`` and Cyclone's reason, instead of a traceback."""
    try:
        yield
    except DDSException as error:
        raise ConfigError(f"{what}: Cyclone refused it ({error})") from None
