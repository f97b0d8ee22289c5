// CanHardware: a Hardware for NodeHandle_ that carries the session's datagrams as CAN transfers
// (protocols/can/CAN.md) through a CAN controller Driver, so the session itself is unchanged.
//
// The session writes COBS-framed bytes: CanHardware collects them up to each 0x00 delimiter,
// decodes the run to the bare native frame (header + payload + CRC-16) and sends it as one
// transfer to the host (node 0) with the priority, kind and channel CAN.md 3 derives from it.
// Each transfer received from the host for this node is COBS-encoded, with its delimiter, into
// the bytes read() returns. Node-id claims go out at start and every second; a claim of our node
// id by another unique id is counted (ownConflicts()). Buffers are bounded; drops are counted.
// To a host whose claims say it takes chains (CAN.md 12), the best-effort fragments of one
// message go as one chained transfer, streamed (ChainSender in transport.h).
//
// Driver concept:
//   bool begin(uint8_t node)                       opens the controller (bit rate set before);
//                                                  one with acceptance filters lets through
//                                                  extended frames to node and NODE messages
//                                                  (claims) to anyone, one without takes all
//                                                  (the transport filters in software anyway)
//   bool receive(hwbridge::can::Frame* f)          a received frame, if any (never blocks)
//   bool send(const hwbridge::can::Frame& f, uint8_t queue_class)
//                                                  queues one frame (may wait briefly for room;
//                                                  false when it cannot: counted, the transfer
//                                                  is abandoned); frames of one queue_class
//                                                  (queue_class() in transport.h) must leave in
//                                                  the order given
//   uint32_t micros(), uint32_t seed()             a wrapping microsecond clock, some entropy
#ifndef HWBRIDGE_CAN_HARDWARE_H
#define HWBRIDGE_CAN_HARDWARE_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "../cobs.h"
#include "transport.h"

namespace hwbridge {
namespace can {

/** Counters of a CanHardware besides its receiver's (they only grow). */
struct CanHardwareStats {
  uint32_t tx_transfers;   ///< transfers sent whole
  uint32_t tx_frames;      ///< frames the driver took
  uint32_t tx_errors;      ///< transfers the driver refused part of (bus off, no room)
  uint32_t tx_oversize;    ///< datagrams longer than MaxDatagram, or not valid COBS (dropped)
  uint32_t rx_overflow;    ///< received datagrams dropped because the read buffer was full
  uint32_t rx_ignored;     ///< transfers for us that were not from the host, or NODE messages
  uint32_t claims_sent;    ///< node-id claims sent
  uint32_t format_changes; ///< times the host's claims changed the format spoken (CAN.md 11)
  uint32_t tx_chains;      ///< chained transfers begun (CAN.md 12)
  uint32_t chain_breaks;   ///< chains left unfinished by a datagram that did not continue them
};

/**
 * Hardware over CAN for board node ids 1..127 (setNode() before the node starts).
 * MaxDatagram: the longest bare datagram either way (negotiate a native MTU of at most
 * MaxDatagram - 5). RxSlots: transfers in reassembly at once. ReadBuffer: bytes of received
 * datagrams (COBS-encoded) waiting for the session.
 */
template <class Driver, size_t MaxDatagram = 72, uint8_t RxSlots = 2,
          size_t ReadBuffer = 2 * (MaxDatagram + 4)>
class CanHardware {
 public:
  static const uint32_t kClaimPeriodUs = 1000000UL;
  /** CAN format 2 carries a frame's header in the id, with no room for flag bit 0 of an ACK in
   * a data frame (PROTOCOL.md 1.4): a node on this link does not announce ACK_IN_DATA. */
  static const bool kNoAckInData = true;
  static const size_t kOutCap = MaxDatagram + MaxDatagram / 254 + 1;

  // constexpr and all zero: a global node lies in .bss, with neither start-up code nor a copy of
  // initial values in flash (node 0 stands for "not set": node 1)
  constexpr CanHardware()
      : stats(), driver_(), receiver_(0), tids_(), watch_(), node_(0), speak1_(false),
        fixed1_(false), host_chains_(false), no_chains_(false), chain_(), uid_(),
        out_(), out_len_(0), out_overflow_(false), ring_(), head_(0), tail_(0), count_(0),
        last_claim_(0), claimed_(false), started_(false) {}

  /** This board's node id (1..127); the host names it in its link (can://.../nodeN). */
  void setNode(uint8_t node) {
    node_ = node & 0x7F;
    if (node_ == 0) node_ = 1;
    receiver_.setLocal(node_);
  }
  uint8_t node() const { return node_ ? node_ : 1; }
  /** Sets the 6-byte unique id of the claims (else one is drawn from seed() at init). */
  void setUid(const uint8_t* uid) { memcpy(uid_, uid, kUidSize); }
  const uint8_t* uid() const { return uid_; }

  Driver& driver() { return driver_; }

  /** Hardware: opens the driver (baud is unused: the bit rate is the driver's). */
  bool init(uint32_t baud = 0) {
    (void)baud;
    if (node_ == 0) setNode(1);
    bool zero = true;
    for (uint8_t i = 0; i < kUidSize; ++i) zero = zero && uid_[i] == 0;
    if (zero) {
      uint32_t s = driver_.seed() ^ (static_cast<uint32_t>(node_) << 24);
      for (uint8_t i = 0; i < kUidSize; ++i) {
        s = s * 1103515245UL + 12345UL;
        uid_[i] = static_cast<uint8_t>(s >> 16);
      }
    }
    started_ = driver_.begin(node_);
    claimed_ = false;
    chain_.cancel();
    return started_;
  }

  /** Hardware: the next byte of received datagrams (COBS, delimited), or -1. */
  int read() {
    if (count_ == 0) poll();
    if (count_ == 0) return -1;
    const uint8_t b = ring_[tail_];
    tail_ = (tail_ + 1) % ReadBuffer;
    --count_;
    return b;
  }

  /** Hardware: one byte of the session's COBS stream; a 0x00 ends a datagram, which is sent. */
  void put(uint8_t b) {
    if (b != 0) {
      if (out_len_ < kOutCap) {
        out_[out_len_++] = b;
      } else {
        out_overflow_ = true;
      }
      return;
    }
    size_t n = 0;
    if (out_len_ > 0) {
      if (out_overflow_ || !cobs_decode(out_, out_len_, out_, &n) || n > MaxDatagram) {
        ++stats.tx_oversize;
      } else {
        sendDatagram(out_, n);
      }
    }
    out_len_ = 0;
    out_overflow_ = false;
  }
  size_t write(const uint8_t* data, size_t n) {
    for (size_t i = 0; i < n; ++i) put(data[i]);
    return n;
  }
  /** Hardware: datagrams are sent as their delimiter arrives; flush() services the bus. */
  void flush() { poll(); }

  uint32_t micros() { return driver_.micros(); }
  uint32_t seed() { return driver_.seed(); }

  /** Reads the driver's frames into the read buffer and sends claims when due. */
  void poll() {
    if (!started_) return;
    const uint32_t now = driver_.micros();
    if (!claimed_ || now - last_claim_ >= kClaimPeriodUs) {
      claimed_ = true;
      last_claim_ = now;
      sendClaim();
    }
    Frame f;
    uint8_t budget = 16;  // frames per poll, so that a flood cannot hold the loop
    while (budget-- && driver_.receive(&f)) {
      Transfer t;
      if (receiver_.feed(f.id, f.extended, f.data, f.len, now, &t)) deliver(t, now);
    }
    receiver_.expire(now);
  }

  /** Sends one bare datagram to the host as a transfer in the format the host claims in;
   * false when the driver refused it (or, in format 2, it is not a valid native datagram:
   * counted as tx_oversize). */
  bool sendDatagram(const uint8_t* datagram, size_t n) {
    // The id carries the datagram's priority (arbitration between nodes); the driver is given
    // its stream's place instead, so that a control datagram never overtakes data queued before
    // it on the same stream (CAN.md 3: the receiver would drop that data as late).
    if (!speak1_) {
      NativeHeader h;
      if (!parse_datagram(datagram, n, &h)) {
        ++stats.tx_oversize;
        return false;
      }
      if (chain_.active() && h.kind == kBestEffort) {  // other streams go beside a chain
        if (chain_.continues(h, n - 5)) return takeChain(datagram + 3, n - 5);
        chain_.cancel();
        ++stats.chain_breaks;
      }
      const uint32_t id = encode_id2(priority_of(h.kind, h.channel), h.kind, h.channel, kHostNode,
                                     node_, h.seq, h.frag);
      if (host_chains_ && chain_.begin(id, h, datagram + 3, n - 5)) {
        ++stats.tx_chains;
        return takeChain(datagram + 7, n - 9);
      }
      return sendFrames(id, queue_class(h.kind), datagram + 3, n - 5, h.seq);
    }
    uint8_t kind;
    uint8_t channel;
    kind_of(datagram, n, &kind, &channel);
    // The id carries the datagram's priority (arbitration between nodes); the driver is given
    // its stream's place instead, so that a control datagram never overtakes data queued before
    // it on the same stream (CAN.md 3: the receiver would drop that data as late).
    const uint8_t id_priority = priority_of(kind, channel);
    return sendTransfer(encode_id(id_priority, kind, channel, kHostNode, node_),
                        queue_class(kind), datagram, n);
  }

  /** The CAN.md format this board speaks: 2 until it hears the host claim in format 1. */
  uint8_t format() const { return speak1_ ? kFormat1 : kFormat2; }
  /** kFormat1: behave as CAN.md version-1 firmware (format 1 only, format-2 frames dropped as
   * malformed), for buses whose other software predates format 2; kFormat2: the default. */
  void setFormat(uint8_t format) {
    fixed1_ = format == kFormat1;
    speak1_ = fixed1_;
    receiver_.setFormat2(!fixed1_);
  }

  /** false: behave as CAN.md version-2 firmware, never sending chained transfers (CAN.md 12);
   * true (the default): chain to a host whose claims say it takes chains. */
  void setChains(bool on) { no_chains_ = !on; }
  /** True while the host's claims say it takes chained transfers (and chains are on). */
  bool hostTakesChains() const { return host_chains_; }

  /** The receiver's counters (CAN.md 5). */
  const CanStats& rxStats() const { return receiver_.stats; }
  /** Claims of this node id by another unique id (two boards configured with one node id). */
  uint32_t ownConflicts() const { return watch_.conflicts; }

  CanHardwareStats stats;

 private:
  struct DriverSink {
    Driver* driver;
    uint8_t priority;
    uint32_t* frames;
    bool operator()(const Frame& f) {
      if (!driver->send(f, priority)) return false;
      ++*frames;
      return true;
    }
  };

  bool takeChain(const uint8_t* data, size_t n) {
    DriverSink sink = {&driver_, kPriorityBestEffort, &stats.tx_frames};
    if (!chain_.take(data, n, sink)) {
      ++stats.tx_errors;
      return false;
    }
    if (!chain_.active()) ++stats.tx_transfers;
    return true;
  }

  bool sendTransfer(uint32_t id, uint8_t priority, const uint8_t* data, size_t n) {
    return sendFrames(id, priority, data, n, tids_.next(id));
  }

  bool sendFrames(uint32_t id, uint8_t priority, const uint8_t* data, size_t n, uint8_t tid) {
    DriverSink sink = {&driver_, priority, &stats.tx_frames};
    if (!send_transfer<kClassicMtu>(id, data, n, tid, kClassicMtu, sink)) {
      ++stats.tx_errors;
      return false;
    }
    ++stats.tx_transfers;
    return true;
  }

  void sendClaim() {
    ++stats.claims_sent;
    const uint32_t id = !speak1_
                            ? encode_id2(kPriorityNode, kNode, kNodeClaim, kHostNode, node_, 0, 0)
                            : encode_id(kPriorityNode, kNode, kNodeClaim, kHostNode, node_);
    sendTransfer(id, kPriorityNode, uid_, kUidSize);
  }

  struct RingSink {
    CanHardware* self;
    void put(uint8_t b) {
      self->ring_[self->head_] = b;
      self->head_ = (self->head_ + 1) % ReadBuffer;
      ++self->count_;
    }
  };

  void deliver(const Transfer& t, uint32_t now) {
    if (t.id.kind == kNode) {
      if (t.id.channel == kNodeClaim && t.size == kUidSize) {
        watch_.claim(t.id.source, node_, t.payload, uid_, now);
        if (t.id.source == kHostNode && (t.id.format == kFormat1) != speak1_ && !fixed1_) {
          speak1_ = t.id.format == kFormat1;  // speak what the host claims in (CAN.md 11)
          ++stats.format_changes;
        }
        if (t.id.source == kHostNode) {  // claim bit 11: the host takes chains (CAN.md 12)
          host_chains_ = !no_chains_ && t.id.format == kFormat2 && (t.id.seq_high & 1) != 0;
        }
      }
      return;
    }
    if (t.id.source != kHostNode || t.id.destination != node_) {
      ++stats.rx_ignored;
      return;
    }
    uint8_t whole[MaxDatagram];
    ByteSpan span = {t.payload, t.size};
    if (t.id.format == kFormat2) {
      // the header and CRC-16 put back must fit what the session takes
      span.size = rebuild_datagram(t, whole, sizeof(whole));
      if (span.size == 0) {
        ++receiver_.stats.oversize;
        return;
      }
      span.data = whole;
    }
    if (cobs_max_encoded(span.size) + 1 > ReadBuffer - count_) {
      ++stats.rx_overflow;
      return;
    }
    RingSink sink = {this};
    cobs_encode_to(span, sink);
    sink.put(0);
  }

  Driver driver_;
  TransferReceiver<MaxDatagram, RxSlots> receiver_;
  TidTable<6> tids_;
  OwnClaimWatch watch_;
  uint8_t node_;
  bool speak1_;  // false: format 2 (members zero by default keep a global board in .bss)
  bool fixed1_;
  bool host_chains_;
  bool no_chains_;
  ChainSender chain_;
  uint8_t uid_[kUidSize];
  uint8_t out_[kOutCap];
  size_t out_len_;
  bool out_overflow_;
  uint8_t ring_[ReadBuffer];
  size_t head_;
  size_t tail_;
  size_t count_;
  uint32_t last_claim_;
  bool claimed_;
  bool started_;
};

}  // namespace can
}  // namespace hwbridge

#endif  // HWBRIDGE_CAN_HARDWARE_H
