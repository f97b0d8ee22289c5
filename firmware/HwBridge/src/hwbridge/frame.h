// Frames of the native protocol (PROTOCOL.md 1.4-1.7): the 3-byte header, the frame types and
// fragment bits, the check of one decoded body, and the sizes.
#ifndef HWBRIDGE_FRAME_H
#define HWBRIDGE_FRAME_H

#include <stddef.h>
#include <stdint.h>

#include "cobs.h"
#include "../hwbridge_wire.h"

namespace hwbridge {

/** Protocol version carried in bits 7-6 of header byte 0. */
static const uint8_t kVersion = 1;
static const size_t kHeaderSize = 3;
static const size_t kCrcSize = 2;
/** Header + CRC: the smallest body (an empty payload). */
static const size_t kEnvelope = kHeaderSize + kCrcSize;
/** Bytes of the uint32 message length at the start of a FIRST fragment's payload. */
static const size_t kLengthPrefix = 4;
/** Smallest payload MTU that fragmentation works with (one data byte per FIRST). */
static const size_t kMinFragmentPayload = kLengthPrefix + 1;
/** Channel of every ACK frame, and of control messages. */
static const uint8_t kControlChannel = 0;
/** Header byte 0, bit 0, of a BEST_EFFORT or RELIABLE frame: the body's byte before the CRC is
 * a cumulative ACK of the other direction (ACK_IN_DATA, PROTOCOL.md 1.4). */
static const uint8_t kAckFlag = 0x01;

/** Header bits 5-4. The value 3 is reserved (a bad frame). */
enum class FrameType : uint8_t { BestEffort = 0, Reliable = 1, Ack = 2 };

/** Header bits 3-2: where a frame's payload sits in its message. */
enum class Frag : uint8_t { Whole = 0, First = 1, Middle = 2, Last = 3 };

/** Result of checking one run or body; Ok for a frame (PROTOCOL.md 1.6, 1.12). */
enum class FrameError : uint8_t {
  Ok = 0,
  Crc,           ///< COBS decoded, but the CRC does not match
  Cobs,          ///< a COBS code points past the end of the run
  TooShort,      ///< a body shorter than 5 bytes
  Version,       ///< a CRC-valid frame of another protocol version
  ReservedType,  ///< a CRC-valid version-1 frame of the reserved type 3
  Oversize,      ///< a run longer than max_frame, or a payload above the MTU
  Text,          ///< non-frame bytes that look like text (a board's debug print)
};

/** One frame. The payload is a view: valid as long as the memory it points into. */
struct Frame {
  FrameType type;
  Frag frag;
  uint8_t channel;
  uint8_t seq;  ///< for an ACK, the acknowledged RELIABLE sequence number
  const uint8_t* payload;
  size_t size;
  bool acked;   ///< a data frame that carries an ACK (kAckFlag): ack is its seq
  uint8_t ack;
};

/** Header byte 0 of a frame: 0x40 | type << 4 | frag << 2. */
inline constexpr uint8_t header_byte0(FrameType type, Frag frag) {
  // (type << 2 | frag) << 2: short shifts of a byte on AVR (type << 4 alone is a multiply there)
  return static_cast<uint8_t>(
      kVersion << 6 |
      static_cast<uint8_t>((static_cast<uint8_t>(type) << 2 | static_cast<uint8_t>(frag)) << 2));
}

/** Largest body for a payload MTU: header + payload + CRC. */
inline constexpr size_t max_body(size_t max_payload) { return max_payload + kEnvelope; }

/** Longest run between delimiters a decoder with this payload MTU accepts (max_frame, 1.6). */
inline constexpr size_t max_frame(size_t max_payload) {
  return cobs_max_encoded(max_body(max_payload));
}

/** Most wire bytes of a frame with n payload bytes (delimiter included, no leading 0x00). */
inline constexpr size_t max_wire_size(size_t n) { return max_frame(n) + 1; }

/**
 * parse_body() after its CRC check: the steps from the version on, of a body of n >= kEnvelope
 * bytes whose CRC matched (a decoder that sums the CRC as the bytes arrive checks it itself).
 */
inline FrameError parse_checked(const uint8_t* body, size_t n, size_t max_payload, Frame* out,
                                bool acks = true) {
  const uint8_t byte0 = body[0];
  if ((byte0 & 0xC0) != kVersion << 6) return FrameError::Version;  // bits, not shifts: AVR
  if ((byte0 & 0x30) == 0x30) return FrameError::ReservedType;      // type 3
  size_t size = n - kEnvelope;
  if (size > max_payload) return FrameError::Oversize;  // the ACK byte counts (1.4)
  // An ACK byte before the CRC: bit 0 on a data frame (an ACK frame's bit 0 is reserved).
  // Without acks, out->acked is left as it was (false in a zeroed Frame): no code for it.
  if (acks) {
    out->acked = (byte0 & (0x20 | kAckFlag)) == kAckFlag;
    if (out->acked) {
      if (size == 0) return FrameError::TooShort;  // the flag, and no byte for the ACK
      --size;
      out->ack = body[n - kCrcSize - 1];
    }
  }
  // Bits 5-4 by a nibble swap (one instruction on AVR, where a shift by 4 is a loop).
  out->type = static_cast<FrameType>(static_cast<uint8_t>(byte0 << 4 | byte0 >> 4) & 3);
  out->frag = static_cast<Frag>((byte0 & 0x0C) >> 2);
  out->channel = body[1];
  out->seq = body[2];
  out->payload = body + kHeaderSize;
  out->size = size;
  return FrameError::Ok;
}

/**
 * Checks one decoded body (header, payload, CRC; steps 4-9 of PROTOCOL.md 1.6) and, when it is
 * a frame, fills *out (its payload points into body). This is also the whole check of a
 * datagram (1.13). acks: a data frame's flag bit 0 means an ACK byte (ACK_IN_DATA, 1.4); false
 * for an end that never announces the feature (its peer never sets the bit, and the code is
 * left out).
 */
inline FrameError parse_body(const uint8_t* body, size_t n, size_t max_payload, Frame* out,
                             bool acks = true) {
  if (n < kEnvelope) return FrameError::TooShort;
  if (crc16(body, n - kCrcSize) != wire::get16(body + n - kCrcSize)) return FrameError::Crc;
  return parse_checked(body, n, max_payload, out, acks);
}

/** The name PROTOCOL.md and the golden vectors give a result ("crc", "cobs", ...). */
inline const char* frame_error_name(FrameError e) {
  switch (e) {
    case FrameError::Ok: return "ok";
    case FrameError::Crc: return "crc";
    case FrameError::Cobs: return "cobs";
    case FrameError::TooShort: return "too_short";
    case FrameError::Version: return "version";
    case FrameError::ReservedType: return "reserved_type";
    case FrameError::Oversize: return "oversize";
    case FrameError::Text: return "text";
  }
  return "?";
}

}  // namespace hwbridge

#endif  // HWBRIDGE_FRAME_H
