// The CAN transport of the native protocol (protocols/can/CAN.md) for boards: the 29-bit id,
// tail bytes, single- and multi-frame transfers with their CRC, and the receiver's checks
// (malformed, foreign, unexpected, duplicate, CRC, abandoned, timeout, oversize), in both
// formats: 1 (the whole native datagram in each transfer) and 2 (CAN.md version 2: the native
// header in the id and the tail byte, no native CRC-16), and the sending side of chained
// transfers (CAN.md version 3, section 12: a message's best-effort fragments as one transfer;
// a board does not take chains, its receiver drops them as malformed). Header-only C++11, no
// heap: every buffer is a member sized by template arguments.
#ifndef HWBRIDGE_CAN_TRANSPORT_H
#define HWBRIDGE_CAN_TRANSPORT_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "../../hwbridge_wire.h"

namespace hwbridge {
namespace can {

static const uint8_t kHostNode = 0;
static const uint8_t kMaxNode = 127;
static const uint8_t kClassicMtu = 8;
static const uint8_t kFdMtu = 64;
static const uint8_t kUidSize = 6;
static const uint8_t kNodeClaim = 1;
static const uint8_t kTidModulo = 32;

enum Kind { kBestEffort = 0, kReliable = 1, kAck = 2, kNode = 3 };

static const uint8_t kPriorityAck = 1;
static const uint8_t kPriorityControl = 2;
static const uint8_t kPriorityNode = 3;
static const uint8_t kPriorityReliable = 4;
static const uint8_t kPriorityBestEffort = 5;

static const uint8_t kStart = 0x80;
static const uint8_t kEnd = 0x40;
static const uint8_t kToggle = 0x20;
static const uint8_t kTidMask = 0x1F;
static const uint32_t kReservedMask = 0x3UL << 14;
static const uint8_t kFormat1 = 1;
static const uint8_t kFormat2 = 2;
static const uint32_t kFormat2Bit = 1UL << 15;
static const uint32_t kToHostBit = 1UL << 14;
static const uint32_t kReserved2Mask = 0x3UL << 7;
static const uint32_t kChainBit = 1UL << 7;
static const uint32_t kClaimChains = 1UL << 11;  ///< in a format-2 claim: takes chains
static const uint16_t kChainMax = 4096;          ///< the longest message chained
static const uint16_t kChainMinSize = 32;        ///< fragment sizes 32 << code, code 0..7

/** id = priority << 26 | kind << 24 | channel << 16 | destination << 7 | source. */
inline uint32_t encode_id(uint8_t priority, uint8_t kind, uint8_t channel, uint8_t destination,
                          uint8_t source) {
  return (static_cast<uint32_t>(priority & 7) << 26) | (static_cast<uint32_t>(kind & 3) << 24) |
         (static_cast<uint32_t>(channel) << 16) | (static_cast<uint32_t>(destination & 0x7F) << 7) |
         (source & 0x7F);
}

/**
 * Format 2: id = priority << 26 | kind << 24 | channel << 16 | 1 << 15 | to_host << 14 |
 * (seq >> 5) << 11 | frag << 9 | board node. One end is the host (node 0).
 */
inline uint32_t encode_id2(uint8_t priority, uint8_t kind, uint8_t channel, uint8_t destination,
                           uint8_t source, uint8_t seq, uint8_t frag) {
  const bool to_host = source != kHostNode;
  const uint8_t node = to_host ? source : destination;
  return (static_cast<uint32_t>(priority & 7) << 26) | (static_cast<uint32_t>(kind & 3) << 24) |
         (static_cast<uint32_t>(channel) << 16) | kFormat2Bit | (to_host ? kToHostBit : 0) |
         (static_cast<uint32_t>(seq >> 5) << 11) | (static_cast<uint32_t>(frag & 3) << 9) |
         (node & 0x7F);
}

/** The fields of a 29-bit id (seq_high and frag: format 2 only). */
struct CanId {
  uint8_t priority;
  uint8_t kind;
  uint8_t channel;
  uint8_t destination;
  uint8_t source;
  uint8_t format;
  uint8_t seq_high;  ///< format 2: bits 7..5 of the native sequence number
  uint8_t frag;      ///< format 2: the native fragment position
};

/** Decodes id (either format) into out; false when it is not one of ours (over 29 bits,
 * reserved bits set, a format-2 id to the host from node 0). */
inline bool decode_id(uint32_t id, CanId* out) {
  if (id >= (1UL << 29)) return false;
  out->priority = static_cast<uint8_t>(id >> 26);
  out->kind = static_cast<uint8_t>((id >> 24) & 3);
  out->channel = static_cast<uint8_t>(id >> 16);
  if (id & kFormat2Bit) {
    const uint8_t node = static_cast<uint8_t>(id & 0x7F);
    const bool to_host = (id & kToHostBit) != 0;
    if ((id & kReserved2Mask) != 0 || (to_host && node == kHostNode)) return false;
    out->destination = to_host ? kHostNode : node;
    out->source = to_host ? node : kHostNode;
    out->format = kFormat2;
    out->seq_high = static_cast<uint8_t>((id >> 11) & 7);
    out->frag = static_cast<uint8_t>((id >> 9) & 3);
    return true;
  }
  if ((id & kReservedMask) != 0) return false;
  out->destination = static_cast<uint8_t>((id >> 7) & 0x7F);
  out->source = static_cast<uint8_t>(id & 0x7F);
  out->format = kFormat1;
  out->seq_high = 0;
  out->frag = 0;
  return true;
}

/** The header fields of a native datagram (PROTOCOL.md 1.4) for format 2. */
struct NativeHeader {
  uint8_t kind;
  uint8_t channel;
  uint8_t seq;
  uint8_t frag;
};

/** Checks a bare native datagram (version 1, a known type, its CRC-16 right) and reads its
 * header; false when it is not one (format 2 must not send it: the receiver rebuilds the CRC). */
inline bool parse_datagram(const uint8_t* d, size_t n, NativeHeader* out) {
  if (n < 5 || (d[0] & 0xC0) != 0x40 || ((d[0] >> 4) & 3) == 3) return false;
  const uint16_t crc = hwbridge::crc16(d, n - 2);
  if (d[n - 2] != static_cast<uint8_t>(crc & 0xFF) || d[n - 1] != static_cast<uint8_t>(crc >> 8)) {
    return false;
  }
  out->kind = static_cast<uint8_t>((d[0] >> 4) & 3);
  out->channel = d[1];
  out->seq = d[2];
  out->frag = static_cast<uint8_t>((d[0] >> 2) & 3);
  return true;
}

/** True for a data length a CAN FD frame can have (0-8, 12, 16, 20, 24, 32, 48, 64). */
inline bool valid_length(size_t n) {
  return n <= 8 || n == 12 || n == 16 || n == 20 || n == 24 || n == 32 || n == 48 || n == 64;
}

/** The largest valid length not above n. */
inline uint8_t round_down_length(size_t n) {
  if (n >= 64) return 64;
  while (!valid_length(n)) --n;
  return static_cast<uint8_t>(n);
}

/** The kind and channel of a bare native datagram (its flags and channel bytes). */
inline void kind_of(const uint8_t* datagram, size_t n, uint8_t* kind, uint8_t* channel) {
  if (n < 2) {
    *kind = kBestEffort;
    *channel = 0;
    return;
  }
  const uint8_t type = static_cast<uint8_t>((datagram[0] >> 4) & 3);
  *kind = type < 3 ? type : static_cast<uint8_t>(kBestEffort);
  *channel = datagram[1];
}

/** The priority a datagram of this kind on this channel is sent with (CAN.md 3). */
inline uint8_t priority_of(uint8_t kind, uint8_t channel) {
  if (kind == kAck) return kPriorityAck;
  if (kind == kNode) return kPriorityNode;
  if (channel == 0) return kPriorityControl;
  return kind == kReliable ? kPriorityReliable : kPriorityBestEffort;
}

/** A sender's queue order for a transfer of `kind` (CAN.md 3): ACKs, NODE messages, then the
 * reliable and the best-effort streams, each in its own order whatever its ids' priorities. */
inline uint8_t queue_class(uint8_t kind) {
  if (kind == kAck) return kPriorityAck;
  if (kind == kNode) return kPriorityNode;
  return kind == kReliable ? kPriorityReliable : kPriorityBestEffort;
}

/** One CAN frame (data up to Mtu bytes). */
template <uint8_t Mtu>
struct FrameT {
  uint32_t id;
  bool extended;
  uint8_t len;
  uint8_t data[Mtu];
};
typedef FrameT<kClassicMtu> Frame;

/**
 * Cuts one transfer of n payload bytes into frames of at most mtu bytes (8, or an FD length
 * 12..64 when the frame type has room) and hands each to sink(const FrameT<Mtu>&), which returns
 * false to stop (the transfer is then incomplete: false is returned). The frames of one
 * transfer come out in order.
 */
template <uint8_t Mtu, class Sink>
bool send_transfer(uint32_t id, const uint8_t* payload, size_t n, uint8_t tid, uint8_t mtu,
                   Sink& sink) {
  FrameT<Mtu> f;
  f.id = id;
  f.extended = true;
  if (mtu > Mtu) mtu = Mtu;
  tid &= kTidMask;
  if (n + 1 <= mtu && valid_length(n + 1)) {
    if (n) memcpy(f.data, payload, n);
    f.data[n] = static_cast<uint8_t>(kStart | kEnd | kToggle | tid);
    f.len = static_cast<uint8_t>(n + 1);
    return sink(f);
  }
  const uint16_t crc = hwbridge::crc16(payload, n);
  const size_t total = n + 2;  // payload and CRC
  size_t offset = 0;
  uint8_t toggle = kToggle;
  bool first = true;
  while (offset < total) {
    const size_t left = total - offset;
    size_t room = first ? left : left + 1;
    if (room > mtu) room = mtu;
    const uint8_t len = round_down_length(room);
    const size_t body = static_cast<size_t>(len - 1);
    for (size_t i = 0; i < body; ++i) {
      const size_t k = offset + i;
      f.data[i] = k < n ? payload[k] : static_cast<uint8_t>(k == n ? crc >> 8 : crc & 0xFF);
    }
    offset += body;
    uint8_t tail = static_cast<uint8_t>(toggle | tid);
    if (first) tail |= kStart;
    if (offset >= total) tail |= kEnd;
    f.data[body] = tail;
    f.len = len;
    if (!sink(f)) return false;
    toggle ^= kToggle;
    first = false;
  }
  return true;
}

/**
 * The chained transfer a board sends (CAN.md 12): the best-effort fragments of one message,
 * FIRST .. LAST, at a power-of-two size, carried as one transfer of the message bytes alone (no
 * length), one transfer CRC, classic frames filled end to end. It streams: each fragment's bytes
 * go out in frames of 7 as they come, at most 7 bytes wait for the next fragment, so a board
 * needs no buffer for the message. Members all zero: a global one is in .bss.
 */
class ChainSender {
 public:
  constexpr ChainSender()
      : frame_(), left_(0), size_(0), crc_(0), toggle_(0), tid_(0), next_seq_(0), channel_(0),
        first_(false), active_(false) {}

  bool active() const { return active_; }
  void cancel() { active_ = false; }

  /** True when a best-effort datagram with header h and n payload bytes is the chain's next
   * fragment. */
  bool continues(const NativeHeader& h, size_t n) const {
    if (!active_ || h.channel != channel_ || h.seq != next_seq_) {
      return false;
    }
    return h.frag == 2 ? n == size_ && left_ > size_ : h.frag == 3 && n == left_ && n <= size_;
  }

  /** Starts a chain with a FIRST fragment (header h, format-2 id id, payload p of n bytes: the
   * length and the first chunk); false, nothing started, when it is not one a chain can carry.
   * Then take() its chunk, p + 4. */
  bool begin(uint32_t id, const NativeHeader& h, const uint8_t* p, size_t n) {
    if (h.kind != kBestEffort || h.frag != 1 || p[2] != 0 || p[3] != 0) return false;
    uint8_t code = 0;
    while ((static_cast<size_t>(kChainMinSize) << code) < n && code < 7) ++code;
    const size_t total = static_cast<size_t>(p[0] | p[1] << 8);
    if ((static_cast<size_t>(kChainMinSize) << code) != n || total <= n - 4 || total > kChainMax) {
      return false;
    }
    // the fragment's id (frag FIRST in bits 10..9) with the chain bit and the size code
    frame_.id = (id & ~(3UL << 9)) | (static_cast<uint32_t>(code) << 8) | kChainBit;
    frame_.extended = true;
    frame_.len = 0;
    left_ = static_cast<uint16_t>(total);
    size_ = static_cast<uint16_t>(n);
    crc_ = hwbridge::kCrcInit;
    toggle_ = kToggle;
    tid_ = static_cast<uint8_t>(h.seq & kTidMask);
    next_seq_ = h.seq;
    channel_ = h.channel;
    first_ = true;
    active_ = true;
    return true;
  }

  /** Takes the next chunk of the message (the FIRST's after its length, then each MIDDLE's
   * and the LAST's payload), giving every frame it completes to sink(const Frame&); with the
   * last chunk the CRC and the end frame. False when the sink refused a frame (the chain is
   * dropped: the receiver's CRC or toggles refuse what it got). */
  template <class Sink>
  bool take(const uint8_t* d, size_t n, Sink& sink) {
    ++next_seq_;
    left_ = static_cast<uint16_t>(left_ - n);
    crc_ = hwbridge::crc16(d, n, crc_);
    if (!put(d, n, sink)) return false;
    if (left_ != 0) return true;
    const uint8_t crc[2] = {static_cast<uint8_t>(crc_ >> 8), static_cast<uint8_t>(crc_)};
    active_ = false;
    return put(crc, 2, sink) && emit(kEnd, sink);
  }

 private:
  // frame_.len counts the bytes waiting in frame_.data (the tail byte goes in at emit)
  template <class Sink>
  bool put(const uint8_t* d, size_t n, Sink& sink) {
    for (size_t i = 0; i < n; ++i) {
      if (frame_.len == kClassicMtu - 1 && !emit(0, sink)) return false;
      frame_.data[frame_.len++] = d[i];
    }
    return true;
  }
  template <class Sink>
  bool emit(uint8_t end, Sink& sink) {
    frame_.data[frame_.len] = static_cast<uint8_t>((first_ ? kStart : 0) | end | toggle_ | tid_);
    ++frame_.len;
    const bool ok = sink(static_cast<const Frame&>(frame_));
    frame_.len = 0;
    first_ = false;
    toggle_ ^= kToggle;
    if (!ok) active_ = false;
    return ok;
  }

  Frame frame_;    // the id, and the bytes waiting for the next frame
  uint16_t left_;  // message bytes still to come
  uint16_t size_;  // fragment size
  uint16_t crc_;
  uint8_t toggle_;
  uint8_t tid_;
  uint8_t next_seq_;
  uint8_t channel_;
  bool first_;
  bool active_;
};

/**
 * A sender's transfer ids: one counter per CAN id, 0..31, for up to Ids ids at once (the ids a
 * board sends on are few: a kind and channel each; past Ids the least recently used is
 * forgotten and its id starts again at 0).
 */
template <uint8_t Ids>
class TidTable {
 public:
  constexpr TidTable() : ids_(), tids_(), stamp_(), used_(0), clock_(0) {}
  /** The transfer id for the next transfer on id (and counts it). */
  uint8_t next(uint32_t id) {
    ++clock_;
    uint8_t victim = 0;
    for (uint8_t i = 0; i < used_; ++i) {
      if (ids_[i] == id) {
        const uint8_t tid = tids_[i];
        tids_[i] = static_cast<uint8_t>((tid + 1) % kTidModulo);
        stamp_[i] = clock_;
        return tid;
      }
      if (stamp_[i] < stamp_[victim]) victim = i;
    }
    const uint8_t slot = used_ < Ids ? used_++ : victim;
    ids_[slot] = id;
    tids_[slot] = 1;
    stamp_[slot] = clock_;
    return 0;
  }

 private:
  uint32_t ids_[Ids];
  uint8_t tids_[Ids];
  uint32_t stamp_[Ids];
  uint8_t used_;
  uint32_t clock_;
};

/** The receiver's counters (CanStats of transport.py; they only grow). */
struct CanStats {
  uint32_t frames;
  uint32_t transfers;
  uint32_t foreign;
  uint32_t malformed;
  uint32_t unexpected;
  uint32_t duplicate_frames;
  uint32_t duplicate_transfers;
  uint32_t crc_errors;
  uint32_t abandoned;
  uint32_t timeouts;
  uint32_t oversize;
  uint32_t error_frames;
  uint32_t dropped() const {
    return malformed + unexpected + duplicate_frames + duplicate_transfers + crc_errors +
           abandoned + timeouts + oversize;
  }
};

/** A transfer returned by TransferReceiver::feed (valid until the next feed). In format 2 the
 * payload is the native datagram's without header and CRC (rebuild_datagram puts them back). */
struct Transfer {
  CanId id;
  uint8_t tid;
  const uint8_t* payload;
  size_t size;
};

/** The native datagram a format-2 transfer carried (header, payload, CRC-16 little-endian)
 * into out (cap bytes); its length, 0 when it does not fit. */
inline size_t rebuild_datagram(const Transfer& t, uint8_t* out, size_t cap) {
  if (t.size + 5 > cap) return 0;
  out[0] = static_cast<uint8_t>(0x40 | (t.id.kind & 3) << 4 | (t.id.frag & 3) << 2);
  out[1] = t.id.channel;
  out[2] = static_cast<uint8_t>(t.id.seq_high << 5 | (t.tid & kTidMask));
  if (t.size) memmove(out + 3, t.payload, t.size);
  const uint16_t crc = hwbridge::crc16(out, t.size + 3);
  out[t.size + 3] = static_cast<uint8_t>(crc & 0xFF);
  out[t.size + 4] = static_cast<uint8_t>(crc >> 8);
  return t.size + 5;
}

/**
 * Reassembles the transfers addressed to local (and NODE messages, whatever their destination)
 * from CAN frames, as CAN.md 5: Slots transfers in progress at once (one per CAN id, the oldest
 * abandoned for a new one), each of at most MaxTransfer bytes; the last completed transfer of
 * up to 2 * Slots ids remembered for 1 s to drop repeats. Times are wrapping microseconds.
 */
template <size_t MaxTransfer, uint8_t Slots = 2>
class TransferReceiver {
 public:
  static const uint32_t kTimeoutUs = 1000000UL;
  static const uint32_t kTidTimeoutUs = 1000000UL;

  // constexpr: a global node holding one is initialized at compile time (in .bss), not by code
  constexpr explicit TransferReceiver(uint8_t local = 0)
      : stats(), local_(local), refuse2_(false), done_next_(0), rx_(), done_() {}
  void setLocal(uint8_t local) { local_ = local; }
  /** false: a CAN.md version-1 receiver (format-2 frames are malformed, as their id bit 15 was
   * reserved). */
  void setFormat2(bool on) { refuse2_ = !on; }
  uint8_t local() const { return local_; }

  /** An error frame seen by the controller. */
  void errorFrame() { ++stats.error_frames; }

  /**
   * Takes one received frame; true when it completes a transfer (then *out describes it: its
   * payload stays valid until the next call, and points into data for a single frame).
   */
  bool feed(uint32_t id, bool extended, const uint8_t* data, size_t len, uint32_t now,
            Transfer* out) {
    ++stats.frames;
    CanId ident;
    if (!extended || !decode_id(id, &ident) || (ident.format == kFormat2 && refuse2_) ||
        len == 0 || len > kFdMtu || !valid_length(len)) {
      ++stats.malformed;
      return false;
    }
    if (ident.destination != local_ && ident.kind != kNode) {
      ++stats.foreign;
      return false;
    }
    const uint8_t tail = data[len - 1];
    const uint8_t tid = tail & kTidMask;
    const uint8_t* body = data;
    const size_t body_len = len - 1;
    Rx* rx = find(id);
    if (tail & kStart) {
      if (!(tail & kToggle)) {
        ++stats.malformed;
        return false;
      }
      if (rx != nullptr) {
        if (rx->frames == 1 && rx->tid == tid && rx->len == body_len &&
            memcmp(rx->buf, body, body_len) == 0) {
          ++stats.duplicate_frames;
          return false;
        }
        rx->busy = false;
        ++stats.abandoned;
      }
      if (tail & kEnd) return finish(id, ident, tid, body, body_len, now, out);
      if (body_len > MaxTransfer + 2) {
        ++stats.oversize;
        return false;
      }
      rx = slot(now);
      rx->busy = true;
      rx->id = id;
      rx->tid = tid;
      rx->toggle = kToggle;
      rx->frames = 1;
      rx->started = now;
      rx->len = body_len;
      memcpy(rx->buf, body, body_len);
      return false;
    }
    if (rx == nullptr) {
      Done* d = findDone(id);
      if (d != nullptr && d->tid == tid && (tail & kEnd)) {
        ++stats.duplicate_frames;
      } else {
        ++stats.unexpected;
      }
      return false;
    }
    if (tid != rx->tid) {
      ++stats.unexpected;
      return false;
    }
    const uint8_t toggle = tail & kToggle;
    if (toggle == rx->toggle) {
      ++stats.duplicate_frames;
      return false;
    }
    if (rx->len + body_len > MaxTransfer + 2) {
      rx->busy = false;
      ++stats.oversize;
      return false;
    }
    rx->toggle = toggle;
    memcpy(rx->buf + rx->len, body, body_len);
    rx->len += body_len;
    ++rx->frames;
    if (!(tail & kEnd)) return false;
    rx->busy = false;
    if (rx->len < 2 || hwbridge::crc16(rx->buf, rx->len) != 0) {
      ++stats.crc_errors;
      return false;
    }
    return finish(id, ident, tid, rx->buf, rx->len - 2, now, out);
  }

  /** Drops (and counts) the transfers in progress for a second or more; how many. */
  uint8_t expire(uint32_t now) {
    uint8_t n = 0;
    for (uint8_t i = 0; i < Slots; ++i) {
      if (rx_[i].busy && now - rx_[i].started >= kTimeoutUs) {
        rx_[i].busy = false;
        ++n;
      }
    }
    stats.timeouts += n;
    return n;
  }

  /** Transfers in progress. */
  uint8_t pending() const {
    uint8_t n = 0;
    for (uint8_t i = 0; i < Slots; ++i) n += rx_[i].busy ? 1 : 0;
    return n;
  }

  CanStats stats;

 private:
  struct Rx {
    uint32_t id;
    uint32_t started;
    size_t len;
    uint8_t tid;
    uint8_t toggle;
    uint8_t frames;
    bool busy;
    uint8_t buf[MaxTransfer + 2];
  };
  struct Done {
    uint32_t id;
    uint32_t when;
    uint16_t check;
    uint8_t tid;
    bool valid;
  };

  Rx* find(uint32_t id) {
    for (uint8_t i = 0; i < Slots; ++i) {
      if (rx_[i].busy && rx_[i].id == id) return &rx_[i];
    }
    return nullptr;
  }
  Rx* slot(uint32_t now) {
    Rx* oldest = &rx_[0];
    for (uint8_t i = 0; i < Slots; ++i) {
      if (!rx_[i].busy) return &rx_[i];
      if (now - rx_[i].started > now - oldest->started) oldest = &rx_[i];
    }
    oldest->busy = false;
    ++stats.abandoned;
    return oldest;
  }
  Done* findDone(uint32_t id) {
    for (uint8_t i = 0; i < 2 * Slots; ++i) {
      if (done_[i].valid && done_[i].id == id) return &done_[i];
    }
    return nullptr;
  }
  bool finish(uint32_t id, const CanId& ident, uint8_t tid, const uint8_t* payload, size_t n,
              uint32_t now, Transfer* out) {
    const uint16_t check = hwbridge::crc16(payload, n);
    Done* d = findDone(id);
    // Format 2 leaves repeats to the session (a resent reliable datagram must get through).
    if (ident.format == kFormat1 && d != nullptr && d->tid == tid && d->check == check &&
        now - d->when < kTidTimeoutUs) {
      ++stats.duplicate_transfers;
      return false;
    }
    if (n > MaxTransfer) {
      ++stats.oversize;
      return false;
    }
    if (d == nullptr) {
      d = &done_[done_next_];
      done_next_ = static_cast<uint8_t>((done_next_ + 1) % (2 * Slots));
    }
    d->valid = true;
    d->id = id;
    d->tid = tid;
    d->when = now;
    d->check = check;
    ++stats.transfers;
    out->id = ident;
    out->tid = tid;
    out->payload = payload;
    out->size = n;
    return true;
  }

  uint8_t local_;
  bool refuse2_;  // all members zero by default: a global receiver stays in .bss
  uint8_t done_next_;
  Rx rx_[Slots];
  Done done_[2 * Slots];
};

/**
 * Node-id claims heard on the bus (CAN.md 2): counts a claim of the watched node id (this
 * board's own) with a unique id other than ours, and any node id claimed by two unique ids
 * within 3 s among the last Nodes node ids heard.
 */
class OwnClaimWatch {
 public:
  constexpr OwnClaimWatch() : conflicts(0), last_conflict(0) {}
  /** A claim of node with unique id uid (kUidSize bytes); true if it contradicts ours. */
  bool claim(uint8_t node, uint8_t own_node, const uint8_t* uid, const uint8_t* own_uid,
             uint32_t now) {
    if (node != own_node || memcmp(uid, own_uid, kUidSize) == 0) return false;
    ++conflicts;
    last_conflict = now;
    return true;
  }
  uint32_t conflicts;
  uint32_t last_conflict;
};

}  // namespace can
}  // namespace hwbridge

#endif  // HWBRIDGE_CAN_TRANSPORT_H
