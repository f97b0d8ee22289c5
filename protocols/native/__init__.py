"""The hwbridge native protocol: framing (``framing``) and sessions (``session``)."""
