"""``python -m hwbridge`` runs the command line."""

from hwbridge.cli import entry

entry()
