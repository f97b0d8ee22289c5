"""Device plugins: host-side logic and emulated models."""
