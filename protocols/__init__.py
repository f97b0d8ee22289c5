"""Wire formats without I/O: native framing and sessions, rosserial v2, device packets."""
