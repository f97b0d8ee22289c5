"""hwbridge: connect microcontroller boards to a host graph of topics and services."""

from hwbridge._version import __version__

__all__ = ["__version__"]
