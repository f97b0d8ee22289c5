"""The native protocol on a CAN bus: 29-bit ids, tail bytes, multi-frame transfers (sans-I/O).

One native datagram (PROTOCOL.md 1.13: header, payload, CRC-16) travels as one CAN *transfer*
of one or more frames; ``CAN.md`` next to this file is the specification and
:mod:`hwbridge.protocols.can.transport` its reference implementation. Links that move the frames
live in :mod:`hwbridge.links.can`.
"""
