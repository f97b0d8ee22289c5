"""Firmware tools: build Arduino sketches for AVR boards and measure them; generate C++ headers."""
