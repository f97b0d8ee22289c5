// The board's own time requests (PROTOCOL.md 2.8): when the next goes out, the last N answers,
// and the one to steer the clock by.
#ifndef HWBRIDGE_TIMESYNC_H
#define HWBRIDGE_TIMESYNC_H

#include <stdint.h>

namespace hwbridge {

/** One answer to a TIME_REQUEST, as a reference pair: at board time board_ref (t4, µs) the host's
 * time was host_sec.host_nsec (t3 + rtt / 2). */
struct TimeSample {
  uint16_t rtt_us;  ///< round trip less the host's busy time (t3 - t2), at most 65535 µs
  uint32_t board_ref;
  uint32_t host_sec, host_nsec;
};

/**
 * A board that asks for the time (N > 0): when its next request is due (a wait from a tick of
 * the node, compared as an unsigned difference: a long pause between timer runs never holds a
 * request back) and its last N samples. add() returns the one to use: the newest whose round
 * trip is within 25 % (or 100 µs) of the smallest kept. A short round trip bounds the error (at
 * most half the difference of the two one-way delays); among similar ones the newest has drifted
 * least.
 */
template <uint8_t N>
class TimeSync {
 public:
  /** The next request is due wait ticks after the tick at. */
  void schedule(uint16_t at, uint16_t wait) {
    at_ = at;
    wait_ = wait;
  }
  bool due(uint16_t tick) const { return static_cast<uint16_t>(tick - at_) >= wait_; }

  const TimeSample& add(const TimeSample& s) {
    const uint8_t newest = next_slot_;
    samples_[newest] = s;
    next_slot_ = static_cast<uint8_t>(newest + 1 == N ? 0 : newest + 1);
    if (count_ < N) ++count_;
    uint16_t best = s.rtt_us;
    for (uint8_t i = 0; i < count_; ++i) {
      if (samples_[i].rtt_us < best) best = samples_[i].rtt_us;
    }
    const uint16_t margin = best / 4 > 100 ? best / 4 : 100;
    uint8_t at = newest;
    for (uint8_t k = 0; k < count_; ++k) {  // the smallest itself ends the search at the latest
      if (static_cast<uint16_t>(samples_[at].rtt_us - best) <= margin) break;
      at = static_cast<uint8_t>(at == 0 ? N - 1 : at - 1);
    }
    return samples_[at];
  }
  /** Forgets every sample (a new session: another host clock, perhaps). */
  void clear() { count_ = next_slot_ = 0; }
  uint8_t count() const { return count_; }

 private:
  uint16_t at_ = 0;
  uint16_t wait_ = 0;
  TimeSample samples_[N] = {};
  uint8_t next_slot_ = 0;
  uint8_t count_ = 0;
};

/** A board that only answers the host's time requests: no requests, no samples (one byte, as
 * every member takes one). */
template <>
class TimeSync<0> {
 public:
  void schedule(uint16_t, uint16_t) {}
  bool due(uint16_t) const { return false; }

  const TimeSample& add(const TimeSample& s) { return s; }
  void clear() {}
  uint8_t count() const { return 0; }
};

}  // namespace hwbridge

#endif  // HWBRIDGE_TIMESYNC_H
