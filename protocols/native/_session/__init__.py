"""The native sessions, in parts; import them from ``hwbridge.protocols.native.session``."""
