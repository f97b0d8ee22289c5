// HwBridge: the board side of the hwbridge native protocol (protocols/PROTOCOL.md).
// Header-only C++11, no heap, no exceptions, no RTTI; sizes are template parameters.
//
// So far: framing (COBS, CRC-16, header, stream decoder, encoder, fragmentation) and the two
// streams (best effort, reliable). The session comes next.
#ifndef HWBRIDGE_H
#define HWBRIDGE_H

#include "hwbridge/config.h"
#include "hwbridge/crc16.h"
#include "hwbridge/cobs.h"
#include "hwbridge/frame.h"
#include "hwbridge/decoder.h"
#include "hwbridge/encoder.h"
#include "hwbridge/fragment.h"
#include "hwbridge/streams.h"

#endif  // HWBRIDGE_H
