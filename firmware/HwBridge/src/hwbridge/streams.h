// The two streams of each direction (PROTOCOL.md 1.8, 2.3, 2.4): best-effort sequence counting,
// and the reliable stream's selective-repeat sender (window, RTO after RFC 6298, backoff, retry
// limit, SACK) and receiver (duplicates, reordering window, cumulative + selective ACKs).
// Sans-I/O: every call takes the time (board microseconds, wrapping uint32) and gives frames.
#ifndef HWBRIDGE_STREAMS_H
#define HWBRIDGE_STREAMS_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "config.h"
#include "encoder.h"
#include "fragment.h"
#include "frame.h"

namespace hwbridge {

/** Largest reliable window (2.11). */
static const uint8_t kMaxWindow = 64;
/** Sequence distances from this one on are behind (late or duplicate), not ahead. */
static const uint8_t kSeqHalf = 128;
/** Longest selective bitmap: 8 bytes (a sender accepts any length up to it). */
static const size_t kMaxSackBytes = 8;

/** a - b in the 8-bit sequence space, 0..255. */
inline uint8_t seq_diff(uint8_t a, uint8_t b) { return static_cast<uint8_t>(a - b); }

/** True when time a is at or after time b (wrapping microseconds, within 35 minutes). */
inline bool time_reached(uint32_t now, uint32_t at) {
  return static_cast<int32_t>(now - at) >= 0;
}

// ---------------------------------------------------------------------------------------------
// Best effort (2.3)

/** Numbers best-effort frames 0, 1, 2, ... from boot, over all channels; never resends. */
class BestEffortSender {
 public:
  constexpr explicit BestEffortSender(uint8_t first_seq = 0) : next_seq_(first_seq), frames_sent_(), messages_sent_() {}

  uint8_t next_seq() const { return next_seq_; }
  /** Takes the next sequence number for one frame. */
  uint8_t take() {
    ++frames_sent_;
    return next_seq_++;
  }

  /**
   * Fragments one message for the peer's MTU and writes its frames to sink.put(), numbered
   * from the next seq; lead puts a 0x00 before the first. False (nothing sent) when the
   * message cannot be split for that MTU.
   */
  template <class Sink>
  bool send(Sink& sink, uint8_t channel, const uint8_t* msg, size_t len, size_t mtu, bool lead = false) {
    Fragmenter frags;
    if (!frags.begin(FrameType::BestEffort, channel, msg, len, mtu)) return false;
    Fragment f;
    while (frags.next(next_seq_, &f)) {
      f.write(sink, lead);
      lead = false;
      take();
    }
    ++messages_sent_;
    return true;
  }

  Counter frames_sent() const { return frames_sent_; }
  Counter messages_sent() const { return messages_sent_; }

 private:
  uint8_t next_seq_;
  TrafficCounter frames_sent_;
  TrafficCounter messages_sent_;
};

struct BestEffortStats {
  TrafficCounter frames_received;  ///< accepted in order
  Counter frames_lost;      ///< counted from gaps in the peer's numbers
  Counter frames_late;      ///< reordered or duplicated, dropped
  TrafficCounter resyncs;  ///< counting restarted on a new peer session
};

/**
 * Counts losses in the peer's best-effort numbers. From the first frame after a resync, a frame
 * d = seq - expected ahead (d < 128) is accepted and d frames were lost; any other is late and
 * dropped. Accepted frames go on to reassembly.
 */
class BestEffortReceiver {
 public:
  constexpr BestEffortReceiver() : stats_(), expected_(0), synced_(false) {}

  /** A new peer session: the next frame counts as the first. */
  void resync() { synced_ = false; }
  bool synced() const { return synced_; }
  uint8_t expected() const { return expected_; }

  /** Accounts for one arriving frame's seq; false when it is late and must be dropped. */
  bool accept(uint8_t seq) {
    uint8_t gap = 0;
    if (!synced_) {
      synced_ = true;
      ++stats_.resyncs;
    } else {
      gap = seq_diff(seq, expected_);
      if (gap >= kSeqHalf) {
        ++stats_.frames_late;
        return false;
      }
    }
    stats_.frames_lost = static_cast<Counter>(stats_.frames_lost + gap);
    ++stats_.frames_received;
    expected_ = static_cast<uint8_t>(seq + 1);
    return true;
  }

  const BestEffortStats& stats() const { return stats_; }

 private:
  BestEffortStats stats_;
  uint8_t expected_;
  bool synced_;
};

// ---------------------------------------------------------------------------------------------
// Reliable (2.4)

/**
 * Smoothed round-trip time and retransmission timeout after RFC 6298, in microseconds: first
 * sample R: SRTT = R, RTTVAR = R/2; later: RTTVAR = 3/4 RTTVAR + 1/4 |SRTT - R|,
 * SRTT = 7/8 SRTT + 1/8 R; RTO = min(rto_max, max(rto_min, SRTT + 4 RTTVAR)).
 */
class RttEstimator {
 public:
  static const uint32_t kInitial = 250000UL;  ///< 0.25 s
  static const uint32_t kMin = 50000UL;       ///< 50 ms (never below 20 ms, 2.4)
  static const uint32_t kMax = 1000000UL;     ///< 1 s

  /** Every member zero (rto_ 0 means kInitial): no constructor code for a global one. */
  constexpr RttEstimator() : srtt_(0), rttvar_(0), rto_(0), sampled_(false) {}

  void sample(uint32_t rtt) {
    if (rtt > 60000000UL) rtt = 60000000UL;  // keeps the arithmetic below in 32 bits
    if (!sampled_) {
      srtt_ = rtt;
      rttvar_ = rtt / 2;
      sampled_ = true;
    } else {
      const uint32_t diff = srtt_ > rtt ? srtt_ - rtt : rtt - srtt_;
      rttvar_ = (3 * rttvar_ + diff) / 4;
      srtt_ = (7 * srtt_ + rtt) / 8;
    }
    uint32_t rto = srtt_ + 4 * rttvar_;
    if (rto < kMin) rto = kMin;
    if (rto > kMax) rto = kMax;
    rto_ = rto;
  }
  /** The timeout of a frame already resent `retries` times: RTO doubled per retry, capped. */
  uint32_t timeout(uint8_t retries) const {
    uint32_t t = rto();
    for (uint8_t i = 0; i < retries && t < kMax; ++i) t <<= 1;
    return t < kMax ? t : kMax;
  }
  uint32_t rto() const { return rto_ ? rto_ : kInitial; }
  /** Smoothed RTT, or 0 before the first sample. */
  uint32_t srtt() const { return srtt_; }
  uint32_t rttvar() const { return rttvar_; }
  bool sampled() const { return sampled_; }

 private:
  uint32_t srtt_;
  uint32_t rttvar_;
  uint32_t rto_;  // 0: kInitial
  bool sampled_;
};

/** The RTO of PROTOCOL.md 2.4's board simplification: fixed (kRto), doubling per retry up to
 * rto_max; no estimate, no state (the interface of RttEstimator). */
class FixedRtt {
 public:
  static const uint32_t kRto = 100000UL;  ///< 0.1 s
  constexpr FixedRtt() {}
  void sample(uint32_t) {}
  uint32_t timeout(uint8_t retries) const {  // kRto * 2^retries: 0.1, 0.2, 0.4, 0.8, then 1 s
    static_assert(kRto << 3 < RttEstimator::kMax && kRto << 4 >= RttEstimator::kMax, "the cap");
    return retries >= 4 ? RttEstimator::kMax : kRto << retries;
  }
  uint32_t rto() const { return kRto; }
  uint32_t srtt() const { return 0; }
  uint32_t rttvar() const { return 0; }
  bool sampled() const { return false; }
};

namespace detail {
template <bool B, class T, class F>
struct Pick {
  typedef T type;
};
template <class T, class F>
struct Pick<false, T, F> {
  typedef F type;
};
}  // namespace detail

struct ReliableSenderStats {
  TrafficCounter frames_sent;  ///< first transmissions
  TrafficCounter messages_sent;
  Counter retransmits;  ///< fast retransmits included
  TrafficCounter fast_retransmits;
  TrafficCounter acks_received;
  Counter refused;      ///< send() calls refused (window full, or a message still being sent)
};

/**
 * The sending half of the reliable stream: selective repeat with up to Window frames of up to
 * MaxPayload bytes in flight, each kept in its own slot until acknowledged.
 *
 * send() copies the frames of a message into free slots at once; a message with more fragments
 * than free slots is sent on as slots free up, from the caller's buffer, which must then stay
 * valid while sending() is true. poll() gives the next frame to transmit: a fast retransmit, a
 * retransmission whose deadline passed (sent + RTO * 2^retries, capped), or a new frame. A frame
 * unacknowledged at the deadline after its max_retries-th retransmission makes dead() true.
 */
template <size_t Window, size_t MaxPayload, bool FixedRto = false>
class ReliableSender {
  static_assert(Window >= 1 && Window <= kMaxWindow, "Window must be 1..64");
  static_assert(MaxPayload >= 1, "MaxPayload must be at least 1");

 public:
  static const bool kTicks = false;  ///< times are microseconds
  constexpr explicit ReliableSender(uint8_t isn = 0, uint8_t max_retries = 10)
      : slots_(), cursor_(), stats_(), rtt_(), mtu_(0), base_(isn), next_seq_(isn), head_(0),
        count_(0), released_(0), window_(0), retry_delta_(static_cast<uint8_t>(max_retries - 10)),
        dead_(false) {}

  /** A new session: forgets every frame, starts at isn; window and mtu are the negotiated ones
   * (capped at Window and MaxPayload). The RTT estimate belongs to the link and is kept. */
  void reset(uint8_t isn, uint8_t window = static_cast<uint8_t>(Window), size_t mtu = MaxPayload) {
    base_ = next_seq_ = isn;
    head_ = count_ = released_ = 0;
    window_ = window == 0 ? 1 : (window > Window ? static_cast<uint8_t>(Window) : window);
    mtu_ = mtu > MaxPayload ? MaxPayload : mtu;
    cursor_.cancel();
    dead_ = false;
  }

  /**
   * Queues one message on channel; false (nothing queued, counted as refused) while a previous
   * message is still being sent, when no slot is free, or when it cannot be fragmented.
   */
  bool send(uint8_t channel, const uint8_t* msg, size_t len) {
    if (!cursor_.done() || count_ >= window() || dead_ ||
        !cursor_.begin(FrameType::Reliable, channel, msg, len, mtu())) {
      ++stats_.refused;
      return false;
    }
    ++stats_.messages_sent;
    fill();
    return true;
  }

  /** A message is partly queued: its buffer must stay valid. */
  bool sending() const { return !cursor_.done(); }
  /** SingleFrameSender's message built in its slot: never here (send() copies, or fragments). */
  static const bool kInPlace = false;
  uint8_t* slot() { return nullptr; }
  void commit(uint8_t, size_t) {}
  /** Nothing queued, nothing waiting for an acknowledgement. */
  bool idle() const { return count_ == 0 && cursor_.done(); }
  /** Slots free for new frames. */
  uint8_t free_slots() const { return static_cast<uint8_t>(window() - count_); }
  /** Frames sent and not yet acknowledged. */
  uint8_t in_flight() const { return released_; }
  /** The peer stopped acknowledging: the link is dead (2.10); reset() to start again. */
  bool dead() const { return dead_; }
  uint8_t base() const { return base_; }
  uint8_t window() const { return window_ ? window_ : static_cast<uint8_t>(Window); }
  size_t mtu() const { return mtu_ ? mtu_ : MaxPayload; }

  /**
   * The next frame to transmit at now, or false when nothing is due. The frame's payload is in
   * its slot: valid until the next call that changes this sender.
   */
  bool poll(uint32_t now, Frame* out) {
    if (dead_) return false;
    fill();
    for (uint8_t i = 0; i < released_; ++i) {  // retransmissions first
      Slot& s = slot(i);
      if (s.sacked) continue;
      const bool fast = s.fast;
      if (!fast && !time_reached(now, s.sent + rtt_.timeout(s.retries))) continue;
      if (!fast && s.retries >= static_cast<uint8_t>(retry_delta_ + 10)) {
        dead_ = true;
        return false;
      }
      s.fast = false;
      ++s.retries;
      s.sent = now;
      ++stats_.retransmits;
      if (fast) ++stats_.fast_retransmits;
      view(s, out);
      return true;
    }
    if (released_ < count_) {
      Slot& s = slot(released_++);
      s.sent = now;
      ++stats_.frames_sent;
      view(s, out);
      return true;
    }
    return false;
  }

  /** FixedRto: the simplification PROTOCOL.md 2.4 allows a board: a fixed RTO (FixedRtt),
   * no RTT estimate, no fast retransmit. */
  typedef typename detail::Pick<FixedRto, FixedRtt, RttEstimator>::type Rtt;

  /** When poll() next has a retransmission to do (false: none; new frames are due at once). */
  bool next_deadline(uint32_t* at) const {
    bool any = false;
    for (uint8_t i = 0; i < released_; ++i) {
      const Slot& s = slot(i);
      if (s.sacked) continue;
      const uint32_t d = s.fast ? s.sent : s.sent + rtt_.timeout(s.retries);
      if (!any || static_cast<int32_t>(d - *at) < 0) *at = d;
      any = true;
    }
    return any;
  }

  /** Handles one ACK frame (cumulative seq + selective bitmap in its payload) received at now. */
  void on_ack(const Frame& ack, uint32_t now) {
    ++stats_.acks_received;
    if (released_ == 0) return;
    const uint8_t upto = seq_diff(ack.seq, base_);
    if (upto < released_) {
      bool resent = false;
      for (uint8_t i = 0; i <= upto; ++i) resent = resent || slot(i).retries != 0;
      const Slot& last = slot(upto);
      if (!FixedRto && !resent && !last.sacked) rtt_.sample(now - last.sent);  // Karn's rule
      const uint8_t n = static_cast<uint8_t>(upto + 1);
      head_ = static_cast<uint8_t>((head_ + n) % Window);
      base_ = static_cast<uint8_t>(base_ + n);
      count_ = static_cast<uint8_t>(count_ - n);
      released_ = static_cast<uint8_t>(released_ - n);
    }
    if (FixedRto) {  // no fast retransmit; SACK bits honoured only when frames can be held
      if (Window > 1) sack(ack);
      fill();
      return;
    }
    const int highest = sack(ack);
    // Fast retransmit: holes below the highest selectively acknowledged frame, at most once
    // per SRTT (RTO before the first sample).
    const uint32_t gap = rtt_.sampled() ? rtt_.srtt() : rtt_.rto();
    for (int i = 0; i < highest; ++i) {
      Slot& s = slot(static_cast<uint8_t>(i));
      if (!s.sacked && !s.fast && static_cast<uint32_t>(now - s.sent) >= gap) s.fast = true;
    }
    fill();
  }

 private:
  /** Marks the frames an ACK's bitmap names as received; the highest one's index, or -1. */
  int sack(const Frame& ack) {
    const size_t bytes = ack.size < kMaxSackBytes ? ack.size : kMaxSackBytes;
    int highest = -1;
    for (size_t b = 0; b < bytes; ++b) {
      const uint8_t bits = ack.payload[b];
      for (uint8_t bit = 0; bits && bit < 8; ++bit) {
        if (!(bits >> bit & 1)) continue;
        const uint8_t seq = static_cast<uint8_t>(ack.seq + 2 + b * 8 + bit);
        const uint8_t i = seq_diff(seq, base_);
        if (i < released_) {
          slot(i).sacked = true;
          highest = i;
        }
      }
    }
    return highest;
  }

 public:
  const ReliableSenderStats& stats() const { return stats_; }
  const Rtt& rtt() const { return rtt_; }
  Rtt& rtt() { return rtt_; }

 private:
  struct Slot {
    uint32_t sent;
    uint8_t seq;
    uint8_t channel;
    Frag frag;
    uint8_t retries;
    bool sacked;
    bool fast;  // resend at the next poll (fast retransmit)
    uint16_t size;
    uint8_t payload[MaxPayload];
  };

  Slot& slot(uint8_t i) { return slots_[(head_ + i) % Window]; }
  const Slot& slot(uint8_t i) const { return slots_[(head_ + i) % Window]; }

  static void view(const Slot& s, Frame* out) {
    out->type = FrameType::Reliable;
    out->frag = s.frag;
    out->channel = s.channel;
    out->seq = s.seq;
    out->payload = s.payload;
    out->size = s.size;
  }

  /** Moves fragments of the current message into free slots. */
  void fill() {
    Fragment f;
    while (count_ < window() && cursor_.next(next_seq_, &f)) {
      Slot& s = slot(count_++);
      s.seq = next_seq_++;
      s.channel = f.header.channel;
      s.frag = f.header.frag;
      s.retries = 0;
      s.sacked = false;
      s.fast = false;
      s.sent = 0;
      s.size = static_cast<uint16_t>(f.payload_size());
      memcpy(s.payload, f.prefix, f.prefix_size);
      if (f.size) memcpy(s.payload + f.prefix_size, f.data, f.size);
    }
  }

  Slot slots_[Window];
  Fragmenter cursor_;
  ReliableSenderStats stats_;
  Rtt rtt_;
  size_t mtu_;        // 0: MaxPayload (every member zero: no constructor code for a global one)
  uint8_t base_;      // oldest unacknowledged seq (slot head_)
  uint8_t next_seq_;  // seq of the next frame put in a slot
  uint8_t head_;
  uint8_t count_;     // slots used: base_ .. base_ + count_ - 1
  uint8_t released_;  // of those, the first released_ have been transmitted
  uint8_t window_;    // 0: Window
  uint8_t retry_delta_;  // max_retries - 10 (mod 256): zero for the default
  bool dead_;
};

/**
 * The reliable sender of the smallest boards: window 1, the fixed RTO of FixedRtt, and no
 * fragmentation (a message above the MTU is refused). The interface of ReliableSender, in a
 * fraction of its code (one slot, one deadline, no fragmenter), except that times are the
 * node's 16-bit ticks of 1.024 ms (kTicks) instead of microseconds.
 */
template <size_t MaxPayload>
class SingleFrameSender {
 public:
  typedef FixedRtt Rtt;
  static const bool kTicks = true;
  /** RTO * 2^retries in ticks: 100, 200, 400, 800 ms, then 1 s. */
  static uint16_t timeout(uint8_t retries) {
    return retries >= 4 ? 977 : static_cast<uint16_t>(98u << retries);
  }

  constexpr SingleFrameSender() : queued_(false), released_(false), dead_(false), retries_(0),
                                  next_seq_(0), channel_(0), sent_(0), size_(0), mtu_(0), stats_(),
                                  rtt_(), payload_() {}

  void reset(uint8_t isn, uint8_t = 1, size_t mtu = MaxPayload) {
    next_seq_ = isn;
    queued_ = released_ = dead_ = false;
    mtu_ = static_cast<uint16_t>(mtu > MaxPayload ? MaxPayload : mtu);
  }

  bool send(uint8_t channel, const uint8_t* msg, size_t len) {
    if (queued_ || dead_ || len > mtu()) {
      ++stats_.refused;
      return false;
    }
    ++stats_.messages_sent;
    channel_ = channel;
    size_ = static_cast<uint16_t>(len);
    if (len) memcpy(payload_, msg, len);
    retries_ = 0;
    queued_ = true;
    return true;
  }

  bool sending() const { return false; }  // a message is copied whole, or refused
  /**
   * kInPlace: while the slot is free (free_slots()), a message can be built right in it (its
   * MaxPayload bytes at slot()) instead of copied there by send(); commit() then queues its len
   * bytes (at most the mtu()) as send() would have. A service's answer saves its copy this way
   * (some 8 cycles a byte on AVR, before its first byte leaves).
   */
  static const bool kInPlace = true;
  uint8_t* slot() { return payload_; }
  void commit(uint8_t channel, size_t len) {
    ++stats_.messages_sent;
    channel_ = channel;
    size_ = static_cast<uint16_t>(len);
    retries_ = 0;
    queued_ = true;
  }
  bool idle() const { return !queued_; }
  uint8_t free_slots() const { return queued_ ? 0 : 1; }
  uint8_t in_flight() const { return released_ ? 1 : 0; }
  bool dead() const { return dead_; }
  uint8_t base() const { return next_seq_; }
  uint8_t window() const { return 1; }
  size_t mtu() const { return mtu_ ? mtu_ : MaxPayload; }

  bool poll(uint16_t now, Frame* out) {
    if (dead_ || !queued_) return false;
    if (released_) {
      if (static_cast<int16_t>(now - static_cast<uint16_t>(sent_ + timeout(retries_))) < 0) return false;
      if (retries_ >= 10) {
        dead_ = true;
        return false;
      }
      ++retries_;
      ++stats_.retransmits;
    } else {
      released_ = true;
      ++stats_.frames_sent;
    }
    sent_ = now;
    out->type = FrameType::Reliable;
    out->frag = Frag::Whole;
    out->channel = channel_;
    out->seq = next_seq_;
    out->payload = payload_;
    out->size = size_;
    return true;
  }

  bool next_deadline(uint16_t* at) const {
    if (!released_) return false;
    *at = static_cast<uint16_t>(sent_ + timeout(retries_));
    return true;
  }

  /** An ACK of the frame in flight frees the slot (a bitmap says nothing at window 1). */
  void on_ack(const Frame& ack, uint32_t) {
    ++stats_.acks_received;
    if (released_ && ack.seq == next_seq_) {
      ++next_seq_;
      queued_ = released_ = false;
    }
  }

  const ReliableSenderStats& stats() const { return stats_; }
  const Rtt& rtt() const { return rtt_; }

 private:
  bool queued_;    // the slot holds a frame
  bool released_;  // ... that was transmitted
  bool dead_;
  uint8_t retries_;
  uint8_t next_seq_;  // the frame in the slot, or the next one
  uint8_t channel_;
  uint16_t sent_;  // ticks
  uint16_t size_;
  uint16_t mtu_;  // 0: MaxPayload
  ReliableSenderStats stats_;
  Rtt rtt_;
  uint8_t payload_[MaxPayload];
};

struct ReliableReceiverStats {
  TrafficCounter frames_received;  ///< accepted (each seq once)
  Counter duplicates;              ///< behind the window or already held
  Counter out_of_window;           ///< too far ahead
  Counter early_dropped;           ///< ahead within the window, but no room to hold it
  TrafficCounter acks_sent;
};

/** What receive() did with a frame. */
enum class Received : uint8_t {
  Deliver,      ///< the expected frame: handle it now, then pop() the frames it releases
  Held,         ///< early: kept until the gap fills
  Duplicate,    ///< dropped (the peer missed an ACK)
  OutOfWindow,  ///< dropped
  Dropped,      ///< early but no slot free to hold it: dropped (the peer resends it)
};

/**
 * The receiving half of the reliable stream: in-order delivery, duplicate suppression and a
 * reordering window of Hold frames of up to MaxPayload bytes (Hold 0: only the expected frame
 * is accepted, as a window-1 board does). Every reliable frame received makes an ACK due.
 */
template <size_t Window, size_t MaxPayload, size_t Hold = Window - 1>
class ReliableReceiver {
  static_assert(Window >= 1 && Window <= kMaxWindow, "Window must be 1..64");
  static_assert(Hold < Window, "Hold must be below Window");

 public:
  constexpr explicit ReliableReceiver(uint8_t isn = 0)
      : held_(), stats_(), expected_(isn), window_(0), ack_every_(0), unacked_(0),
        ack_needed_(false), ack_urgent_(false), popped_(false) {}

  /** A new session: expects the peer's isn first; window is the negotiated one (<= Window). */
  void reset(uint8_t isn, uint8_t window = static_cast<uint8_t>(Window)) {
    expected_ = isn;
    window_ = window == 0 ? 1 : (window > Window ? static_cast<uint8_t>(Window) : window);
    ack_every_ = window_ >= 4 ? static_cast<uint8_t>(window_ / 2) : 1;
    ack_needed_ = ack_urgent_ = false;
    unacked_ = 0;
    for (size_t i = 0; i < kSlots; ++i) {
      held_[i].used = false;
      held_[i].seq = 0;
    }
  }

  /** Takes one RELIABLE frame. On Deliver, expected() has moved past it. */
  __attribute__((noinline)) Received receive(const Frame& f) {
    ack_needed_ = true;
    popped_ = false;
    const uint8_t ahead = seq_diff(f.seq, expected_);
    if (ahead >= kSeqHalf || find(f.seq) >= 0) {
      ++stats_.duplicates;
      ack_urgent_ = true;
      return Received::Duplicate;
    }
    if (ahead >= (window_ ? window_ : Window)) {
      ++stats_.out_of_window;
      ack_urgent_ = true;
      return Received::OutOfWindow;
    }
    if (ahead) {
      ack_urgent_ = true;  // a gap: the bitmap lets the peer resend at once
      for (size_t i = 0; i < Hold; ++i) {
        if (held_[i].used || f.size > MaxPayload) continue;
        Slot& s = held_[i];
        s.used = true;
        s.seq = f.seq;
        s.channel = f.channel;
        s.frag = f.frag;
        s.size = static_cast<uint16_t>(f.size);
        if (f.size) memcpy(s.payload, f.payload, f.size);
        ++stats_.frames_received;
        return Received::Held;
      }
      ++stats_.early_dropped;
      return Received::Dropped;
    }
    ++stats_.frames_received;
    expected_ = static_cast<uint8_t>(expected_ + 1);
    if (held() != 0) {
      ack_urgent_ = true;  // it releases held frames, or a gap remains after it
    } else if (++unacked_ >= (window_ ? ack_every_ : (Window >= 4 ? Window / 2 : 1))) {
      ack_urgent_ = true;
    }
    return Received::Deliver;
  }

  /** The next held frame that is now in order, or false. Its payload is valid until the next
   * receive(). */
  bool pop(Frame* out) {
    const int i = find(expected_);
    if (i < 0) return false;
    Slot& s = held_[i];
    s.used = false;
    popped_ = true;
    out->type = FrameType::Reliable;
    out->frag = s.frag;
    out->channel = s.channel;
    out->seq = s.seq;
    out->payload = s.payload;
    out->size = s.size;
    expected_ = static_cast<uint8_t>(expected_ + 1);
    return true;
  }

  uint8_t expected() const { return expected_; }
  /**
   * Takes back the frame receive() delivered last, whose message cannot be handled now: it is
   * expected again, the ACK that goes out does not cover it, and the peer sends it again after
   * its RTO. False when the frame came from pop() instead (a held frame, which the peer may
   * already know as received from a bitmap, and would never resend).
   */
  bool refuse() {
    if (popped_) return false;
    expected_ = static_cast<uint8_t>(expected_ - 1);
    --stats_.frames_received;
    return true;
  }
  /** An ACK is due (every reliable frame received asks for one). */
  bool ack_needed() const { return ack_needed_; }
  /** The due ACK must not be held back (2.4, delayed ACKs). */
  bool ack_urgent() const { return ack_urgent_; }
  /** Frames held early. */
  uint8_t held() const {
    uint8_t n = 0;
    for (size_t i = 0; i < Hold; ++i) n = static_cast<uint8_t>(n + (held_[i].used ? 1 : 0));
    return n;
  }

  /**
   * The ACK for the current state: returns its seq (expected - 1) and writes the selective
   * bitmap (bit i: seq + 2 + i held; trailing zero bytes left out) to bitmap, *bitmap_len its
   * length (at most kMaxSackBytes). Clears the due flags.
   */
  uint8_t make_ack(uint8_t* bitmap, size_t* bitmap_len) {
    ack_needed_ = ack_urgent_ = false;
    unacked_ = 0;
    ++stats_.acks_sent;
    size_t len = 0;
    for (size_t i = 0; i < Hold; ++i) {
      if (!held_[i].used) continue;
      const uint8_t bit = static_cast<uint8_t>(seq_diff(held_[i].seq, expected_) - 1);
      const size_t byte = bit / 8u;
      while (len <= byte) bitmap[len++] = 0;
      bitmap[byte] = static_cast<uint8_t>(bitmap[byte] | (1u << (bit % 8u)));
    }
    *bitmap_len = len;
    return static_cast<uint8_t>(expected_ - 1);
  }

  /** Writes the ACK frame (channel 0, frag WHOLE) to sink.put(); clears the due flags. */
  template <class Sink>
  size_t write_ack(Sink& sink, bool lead = false) {
    uint8_t bitmap[kMaxSackBytes] = {0};
    size_t n = 0;
    FrameHeader h;
    h.type = FrameType::Ack;
    h.frag = Frag::Whole;
    h.channel = kControlChannel;
    h.seq = make_ack(bitmap, &n);
    return write_frame(sink, h, bitmap, n, nullptr, 0, lead);
  }

  const ReliableReceiverStats& stats() const { return stats_; }

 private:
  static const size_t kSlots = Hold ? Hold : 1;

  struct Slot {
    uint8_t seq;
    uint8_t channel;
    Frag frag;
    bool used;
    uint16_t size;
    uint8_t payload[Hold ? MaxPayload : 1];
  };

  int find(uint8_t seq) const {
    for (size_t i = 0; i < Hold; ++i) {
      if (held_[i].used && held_[i].seq == seq) return static_cast<int>(i);
    }
    return -1;
  }

  Slot held_[kSlots];
  ReliableReceiverStats stats_;
  uint8_t expected_;
  uint8_t window_;     // 0: Window (every member zero: no constructor code for a global one)
  uint8_t ack_every_;
  uint8_t unacked_;
  bool ack_needed_;
  bool ack_urgent_;
  bool popped_;  // the frame delivered last came from pop()
};

/**
 * The reliable receiver of a window-1 board that holds no early frames: the interface and the
 * behaviour of ReliableReceiver<1, MaxPayload, 0> (only the expected seq is accepted, anything
 * behind it is a duplicate, anything ahead is outside the window, every reliable frame makes
 * an ACK due and each one is urgent, an ACK carries expected - 1 and never a bitmap), in a
 * fraction of its code: no slots, no window arithmetic.
 */
template <size_t MaxPayload>
class SingleFrameReceiver {
 public:
  constexpr explicit SingleFrameReceiver(uint8_t isn = 0)
      : stats_(), expected_(isn), ack_needed_(false) {}

  /** A new session: expects the peer's isn first (any window is 1 here). */
  void reset(uint8_t isn, uint8_t = 1) {
    expected_ = isn;
    ack_needed_ = false;
  }

  /** Takes one RELIABLE frame. On Deliver, expected() has moved past it. */
  Received receive(const Frame& f) {
    ack_needed_ = true;
    const uint8_t ahead = seq_diff(f.seq, expected_);
    if (ahead == 0) {
      ++stats_.frames_received;
      ++expected_;
      return Received::Deliver;
    }
    if (ahead >= kSeqHalf) {
      ++stats_.duplicates;
      return Received::Duplicate;
    }
    ++stats_.out_of_window;
    return Received::OutOfWindow;
  }

  /** Nothing is ever held. */
  bool pop(Frame*) { return false; }

  uint8_t expected() const { return expected_; }
  /** Takes back the frame receive() delivered last (ReliableReceiver::refuse; every frame
   * delivered here came from receive()). */
  bool refuse() {
    --expected_;
    --stats_.frames_received;
    return true;
  }
  /** An ACK is due (every reliable frame received asks for one). */
  bool ack_needed() const { return ack_needed_; }
  /** At window 1 every due ACK is urgent. */
  bool ack_urgent() const { return ack_needed_; }
  uint8_t held() const { return 0; }

  /** The ACK for the current state: its seq (expected - 1); no bitmap. Clears the due flag. */
  uint8_t make_ack(uint8_t*, size_t* bitmap_len) {
    ack_needed_ = false;
    ++stats_.acks_sent;
    *bitmap_len = 0;
    return static_cast<uint8_t>(expected_ - 1);
  }

  /** Writes the ACK frame (channel 0, frag WHOLE, empty payload); clears the due flag. */
  template <class Sink>
  size_t write_ack(Sink& sink, bool lead = false) {
    ack_needed_ = false;
    ++stats_.acks_sent;
    FrameHeader h;
    h.type = FrameType::Ack;
    h.frag = Frag::Whole;
    h.channel = kControlChannel;
    h.seq = static_cast<uint8_t>(expected_ - 1);
    return write_frame(sink, h, nullptr, 0, nullptr, 0, lead);
  }

  const ReliableReceiverStats& stats() const { return stats_; }

 private:
  ReliableReceiverStats stats_;
  uint8_t expected_;
  bool ack_needed_;
};

}  // namespace hwbridge

#endif  // HWBRIDGE_STREAMS_H
