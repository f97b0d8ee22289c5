"""The native framing, in parts (import it from ``hwbridge.protocols.native.framing``)."""
