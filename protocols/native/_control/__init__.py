"""The native control messages, by group (import them from ``native.control``)."""
