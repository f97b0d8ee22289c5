// Fragmentation and reassembly (PROTOCOL.md 1.9): a message larger than the peer's MTU goes as
// FIRST (uint32 length + chunk), MIDDLE..., LAST; the receiver joins them in a bounded buffer.
#ifndef HWBRIDGE_FRAGMENT_H
#define HWBRIDGE_FRAGMENT_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "config.h"
#include "../hwbridge_wire.h"
#include "encoder.h"
#include "frame.h"

namespace hwbridge {

/** Frames a message of len bytes takes with payload MTU mtu (0 when it cannot be split). */
inline size_t fragment_count(size_t len, size_t mtu) {
  if (len <= mtu) return 1;
  if (mtu < kMinFragmentPayload) return 0;
  const size_t rest = len - (mtu - kLengthPrefix);
  return 1 + (rest + mtu - 1) / mtu;
}

/** One fragment to send: its header and its payload as prefix (0 or 4 bytes) + data. */
struct Fragment {
  FrameHeader header;
  uint8_t prefix[kLengthPrefix];
  size_t prefix_size;
  const uint8_t* data;
  size_t size;
  /** Payload bytes in all: prefix_size + size. */
  size_t payload_size() const { return prefix_size + size; }
  /** Writes this fragment as one frame on the wire (see write_frame). */
  template <class Sink>
  size_t write(Sink& sink, bool lead = false) const {
    return write_frame(sink, header, prefix, prefix_size, data, size, lead);
  }
};

/**
 * Splits one message into fragments for a payload MTU, without copying it: the message must
 * stay valid until the last fragment was taken. Sequence numbers are the caller's (the next of
 * the stream's space for each fragment).
 */
class Fragmenter {
 public:
  constexpr Fragmenter() : msg_(nullptr), len_(0), pos_(0), mtu_(0), type_(FrameType::BestEffort), channel_(0), active_(false) {}

  /**
   * Starts a message. False (nothing started) for an ACK type, or for a message larger than the
   * MTU when the MTU is below kMinFragmentPayload.
   */
  bool begin(FrameType type, uint8_t channel, const uint8_t* msg, size_t len, size_t mtu) {
    // fragment_count(len, mtu) == 0, without its division (a board's sender never counts)
    if (type == FrameType::Ack || (len > mtu && mtu < kMinFragmentPayload)) return false;
    msg_ = msg;
    len_ = len;
    pos_ = 0;
    mtu_ = mtu;
    type_ = type;
    channel_ = channel;
    active_ = true;
    return true;
  }
  /** Fragments still to take. */
  size_t remaining() const {
    if (!active_) return 0;
    return pos_ == 0 ? fragment_count(len_, mtu_) : (len_ - pos_ + mtu_ - 1) / mtu_;
  }
  bool done() const { return !active_; }
  void cancel() { active_ = false; }

  /** Takes the next fragment, numbered seq; false when the message is done. */
  bool next(uint8_t seq, Fragment* out) {
    if (!active_) return false;
    out->header.type = type_;
    out->header.channel = channel_;
    out->header.seq = seq;
    out->prefix_size = 0;
    out->data = msg_ + pos_;
    if (pos_ == 0 && len_ <= mtu_) {
      out->header.frag = Frag::Whole;
      out->size = len_;
    } else if (pos_ == 0) {
      out->header.frag = Frag::First;
      wire::put32(out->prefix, static_cast<uint32_t>(len_));
      out->prefix_size = kLengthPrefix;
      out->size = mtu_ - kLengthPrefix;
    } else {
      const size_t rest = len_ - pos_;
      out->header.frag = rest <= mtu_ ? Frag::Last : Frag::Middle;
      out->size = rest <= mtu_ ? rest : mtu_;
    }
    pos_ += out->size;
    if (pos_ >= len_) active_ = false;  // the WHOLE or LAST fragment was taken
    return true;
  }

 private:
  const uint8_t* msg_;
  size_t len_;
  size_t pos_;
  size_t mtu_;
  FrameType type_;
  uint8_t channel_;
  bool active_;  // a fragment is still to take
};

/** Counters of a Reassembler. */
struct ReassemblyStats {
  TrafficCounter messages;  ///< complete messages returned (WHOLE frames included)
  Counter dropped_partial;  ///< partial messages abandoned (a gap, another channel, a new FIRST/WHOLE)
  Counter oversize;         ///< messages whose announced length is above MaxMessage
  Counter orphans;          ///< MIDDLE/LAST fragments that continue no message (dropped)
  Counter malformed;        ///< FIRST too short, or fragments disagreeing with the length
  Counter duplicates;       ///< repeats of the last frame accepted (ignored)
};

/** One complete message. data is a view: valid until the next feed (or the frame's buffer). */
struct Message {
  uint8_t channel;
  uint8_t seq;  ///< seq of its first (or only) frame
  const uint8_t* data;
  size_t size;
};

/**
 * Joins fragments into messages in one buffer of MaxMessage bytes, shared by the two receive
 * spaces (BEST_EFFORT and RELIABLE), as PROTOCOL.md 1.9 allows a device to: a FIRST in one
 * space abandons a partial message of the other (counted as a dropped partial); frames of a
 * space are otherwise handled on their own. Feed frames in arrival order (RELIABLE ones in the
 * order the reliable receiver delivers them). WHOLE frames need no buffer: a Reassembler<0>
 * delivers them and refuses every fragmented message as oversize (without counting its other
 * fragments as orphans), in little code. A message is returned only
 * when exactly its announced length arrived in consecutive fragments; memory never grows.
 */
template <size_t MaxMessage>
class Reassembler {
 public:
  /** Every member zero: a global one is in .bss, with no constructor code. */
  constexpr Reassembler() : spaces_(), stats_(), total_(0), held_(0), owner_(kNone), buf_() {}

  /** Abandons any partial message (counted) and forgets the last frames of both spaces. */
  void reset() {
    abandon();
    for (uint8_t i = 0; i < 2; ++i) {
      spaces_[i].has_last = false;
      spaces_[i].skipping = false;
      spaces_[i].next_seq = 0;
      spaces_[i].channel = 0;
      spaces_[i].first_seq = 0;
    }
  }
  /** Abandons a partial message of one space (a new peer session). */
  void reset(FrameType type) {
    if (type == FrameType::Ack) return;
    const uint8_t s = static_cast<uint8_t>(type);
    if (owner_ == s + 1) abandon();
    spaces_[s].has_last = false;
    spaces_[s].skipping = false;
  }

  /** True while a partial message of this space is held. */
  bool in_progress(FrameType type) const { return owner_ == static_cast<uint8_t>(type) + 1; }
  /** Bytes of the partial message held. */
  size_t buffered() const { return owner_ == kNone ? 0 : held_; }
  const ReassemblyStats& stats() const { return stats_; }
  static size_t capacity() { return MaxMessage; }

  /**
   * Forgets the reliable message feed() returned last when it was one WHOLE frame, so that the
   * same frame is taken again when its sender repeats it (the node took it back from the
   * reliable receiver: it could not be handled now). False for a message of fragments, which
   * cannot be taken back (its earlier frames were acknowledged already).
   */
  bool unfeed() {
    Space& sp = spaces_[static_cast<uint8_t>(FrameType::Reliable)];
    if (!sp.has_last || sp.last_frag != Frag::Whole) return false;
    sp.has_last = false;
    return true;
  }

  /** Consumes one frame; true with *out when it completes a message. ACK frames are ignored. */
  bool feed(const Frame& f, Message* out) {
    if (f.type == FrameType::Ack) return false;
    const uint8_t s = static_cast<uint8_t>(f.type);
    Space& sp = spaces_[s];
    const uint16_t crc = crc16(f.payload, f.size);
    if (sp.has_last && sp.last_seq == f.seq && sp.last_channel == f.channel &&
        sp.last_frag == f.frag && sp.last_size == f.size && sp.last_crc == crc) {
      ++stats_.duplicates;
      return false;
    }
    if (MaxMessage == 0 && f.frag != Frag::Whole) {
      // No buffer: a FIRST refuses its message (it cannot be held), and the MIDDLE and LAST
      // frames after it are dropped without being counted again.
      if (f.frag == Frag::First) ++stats_.oversize;
      sp.has_last = false;
      return false;
    }
    switch (f.frag) {
      case Frag::Whole:
        if (owner_ == s + 1) abandon();
        remember(sp, f, crc);
        ++stats_.messages;
        out->channel = f.channel;
        out->seq = f.seq;
        out->data = f.payload;
        out->size = f.size;
        return true;
      case Frag::First:
        first(s, f, crc);
        return false;
      case Frag::Middle:
      case Frag::Last:
        break;
    }
    return next(s, f, crc, out);
  }

 private:
  static const uint8_t kNone = 0;

  struct Space {
    uint16_t last_crc;
    size_t last_size;
    uint8_t last_seq;
    uint8_t last_channel;
    Frag last_frag;
    bool has_last;
    bool skipping;  // swallowing the fragments of a refused (oversize) message
    uint8_t next_seq;
    uint8_t channel;
    uint8_t first_seq;
  };

  void abandon() {
    if (owner_ != kNone) {
      ++stats_.dropped_partial;
      spaces_[owner_ - 1].skipping = false;
    }
    owner_ = kNone;
  }

  static void remember(Space& sp, const Frame& f, uint16_t crc) {
    sp.has_last = true;
    sp.last_seq = f.seq;
    sp.last_channel = f.channel;
    sp.last_frag = f.frag;
    sp.last_size = f.size;
    sp.last_crc = crc;
    sp.next_seq = static_cast<uint8_t>(f.seq + 1);
  }

  void first(uint8_t s, const Frame& f, uint16_t crc) {
    Space& sp = spaces_[s];
    abandon();  // this space's partial message, or the other's: the buffer is shared
    sp.skipping = false;
    sp.has_last = false;
    if (f.size < kLengthPrefix) {
      ++stats_.malformed;
      return;
    }
    const uint32_t total = wire::get32(f.payload);
    const size_t chunk = f.size - kLengthPrefix;
    sp.channel = f.channel;
    sp.first_seq = f.seq;
    remember(sp, f, crc);
    if (total > MaxMessage) {
      ++stats_.oversize;
      sp.skipping = true;
      return;
    }
    if (chunk > total) {
      ++stats_.malformed;
      return;
    }
    total_ = static_cast<size_t>(total);
    held_ = chunk;
    if (chunk) memcpy(buf_, f.payload + kLengthPrefix, chunk);
    owner_ = static_cast<uint8_t>(s + 1);
  }

  bool next(uint8_t s, const Frame& f, uint16_t crc, Message* out) {
    Space& sp = spaces_[s];
    const bool mine = owner_ == s + 1;
    if (!mine && !sp.skipping) {
      ++stats_.orphans;
      return false;
    }
    if (f.seq != sp.next_seq || f.channel != sp.channel) {
      if (mine) abandon();
      sp.skipping = false;
      sp.has_last = false;
      ++stats_.orphans;
      return false;
    }
    remember(sp, f, crc);
    const bool last = f.frag == Frag::Last;
    if (!mine) {  // skipping an oversize message
      if (last) sp.skipping = false;
      return false;
    }
    if (f.size > total_ - held_ || (last && held_ + f.size != total_)) {
      owner_ = kNone;
      ++stats_.malformed;
      return false;
    }
    if (f.size) memcpy(buf_ + held_, f.payload, f.size);
    held_ += f.size;
    if (!last) return false;
    owner_ = kNone;
    ++stats_.messages;
    out->channel = f.channel;
    out->seq = sp.first_seq;
    out->data = buf_;
    out->size = held_;
    return true;
  }

  Space spaces_[2];
  ReassemblyStats stats_;
  size_t total_;
  size_t held_;
  uint8_t owner_;  // 1 + the space (0 best effort, 1 reliable) whose partial message is held; 0 none
  uint8_t buf_[MaxMessage ? MaxMessage : 1];  // last: the fuzz tests' guards sit right after it
};

/**
 * No reassembly buffer: WHOLE frames are delivered, every fragmented message is refused as
 * oversize (its FIRST counted), in little code and RAM. Repeats are not detected here (the
 * streams drop them before: late best-effort frames, reliable duplicates).
 */
template <>
class Reassembler<0> {
 public:
  constexpr Reassembler() : stats_() {}
  void reset() {}
  void reset(FrameType) {}
  bool in_progress(FrameType) const { return false; }
  size_t buffered() const { return 0; }
  const ReassemblyStats& stats() const { return stats_; }
  static size_t capacity() { return 0; }
  /** Every message here is one WHOLE frame, and no repeat is remembered: nothing to forget. */
  bool unfeed() { return true; }
  bool feed(const Frame& f, Message* out) {
    if (f.type == FrameType::Ack) return false;
    if (f.frag != Frag::Whole) {
      if (f.frag == Frag::First) ++stats_.oversize;
      return false;
    }
    ++stats_.messages;
    out->channel = f.channel;
    out->seq = f.seq;
    out->data = f.payload;
    out->size = f.size;
    return true;
  }

 private:
  ReassemblyStats stats_;
};

}  // namespace hwbridge

#endif  // HWBRIDGE_FRAGMENT_H
