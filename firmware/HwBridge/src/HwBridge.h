// HwBridge: the board side of the hwbridge native protocol (protocols/PROTOCOL.md).
// Header-only C++11, no heap, no exceptions, no RTTI; sizes are template parameters.
//
// Framing (COBS, CRC-16, header, stream decoder, encoder, fragmentation), the two streams (best
// effort, reliable), and the session with its rosserial-like API (hwbridge/node.h): NodeHandle,
// Publisher, Subscriber, ServiceServer, ServiceClient, parameters, logs, host time.
#ifndef HWBRIDGE_H
#define HWBRIDGE_H

#include "hwbridge/config.h"
#include "hwbridge_wire.h"
#include "hwbridge/cobs.h"
#include "hwbridge/frame.h"
#include "hwbridge/decoder.h"
#include "hwbridge/encoder.h"
#include "hwbridge/fragment.h"
#include "hwbridge/streams.h"
#include "hwbridge/node.h"

#endif  // HWBRIDGE_H
