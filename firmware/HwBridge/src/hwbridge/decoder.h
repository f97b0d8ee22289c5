// The stream decoder (PROTOCOL.md 1.6): bytes in, frames out, through one bounded buffer.
#ifndef HWBRIDGE_DECODER_H
#define HWBRIDGE_DECODER_H

#include <stddef.h>
#include <stdint.h>

#include "cobs.h"
#include "config.h"
#include "frame.h"

namespace hwbridge {

/** Counters of a FrameDecoder: every rejected run is counted once. */
struct DecoderStats {
  Counter frames;           ///< valid frames returned
  Counter crc_errors;
  Counter cobs_errors;
  Counter too_short;
  Counter version_errors;
  Counter reserved_type;
  Counter oversize;         ///< runs longer than max_frame and payloads above the MTU
  Counter non_frame_bytes;  ///< bytes of runs reported as text (bytes, not runs)
};

/** Where the counter of a result (frames for Ok) sits in DecoderStats: the counters follow
 * FrameError's order, so that FrameDecoder finds one by number instead of by a switch. */
inline constexpr size_t counter_offset(FrameError e) {
  return static_cast<uint8_t>(e) * sizeof(Counter);
}
static_assert(offsetof(DecoderStats, frames) == counter_offset(FrameError::Ok) &&
                  offsetof(DecoderStats, crc_errors) == counter_offset(FrameError::Crc) &&
                  offsetof(DecoderStats, cobs_errors) == counter_offset(FrameError::Cobs) &&
                  offsetof(DecoderStats, too_short) == counter_offset(FrameError::TooShort) &&
                  offsetof(DecoderStats, version_errors) == counter_offset(FrameError::Version) &&
                  offsetof(DecoderStats, reserved_type) == counter_offset(FrameError::ReservedType) &&
                  offsetof(DecoderStats, oversize) == counter_offset(FrameError::Oversize),
              "DecoderStats: one counter per FrameError, in its order");

/** What one byte completed. */
enum class Decoded : uint8_t {
  Nothing,  ///< no run ended, or an empty run (a leading delimiter)
  Frame,    ///< a frame: FrameDecoder::frame()
  Bad,      ///< a rejected run: FrameDecoder::error() says why (counted)
};

namespace detail {

/** Text detection (DetectText): how many bytes of a run were printable ASCII (TAB, LF, CR
 * included), over the first 65535 bytes of the run. */
template <bool DetectText>
struct TextCount {
  uint16_t total;      // bytes of the run, also past the buffer
  uint16_t printable;  // printable bytes among them
  constexpr TextCount() : total(0), printable(0) {}
  void add(uint8_t b) {
    if (total == 0xFFFFu) return;  // the ratio of the first 65535 bytes
    ++total;
    if ((b >= 0x20 && b <= 0x7E) || b == 9 || b == 10 || b == 13) ++printable;
  }
  /** At least 90 % printable. */
  bool text() const {
    return total > 0 && static_cast<uint32_t>(printable) * 10u >= static_cast<uint32_t>(total) * 9u;
  }
  size_t bytes() const { return total; }
  void clear() { total = printable = 0; }
};

/** Without text detection: nothing counted, nothing is text. */
template <>
struct TextCount<false> {
  constexpr TextCount() {}
  void add(uint8_t) {}
  bool text() const { return false; }
  size_t bytes() const { return 0; }
  void clear() {}
};

/** The type of a count up to N + 1: one byte when it fits (an 8-bit board's registers). */
template <bool Small>
struct RunIndex {
  typedef uint8_t type;
};
template <>
struct RunIndex<false> {
  typedef size_t type;
};

/** A FrameDecoder's payload slack (MaxPayload - the run-time MTU, below the buffer's size); a
 * FixedMtu decoder has none, and no byte for it (an empty base). */
template <bool FixedMtu, class Index>
class DecoderSlack {
 public:
  constexpr DecoderSlack() : slack_(0) {}
  Index slack() const { return slack_; }
  void set_slack(Index s) { slack_ = s; }

 private:
  Index slack_;
};
template <class Index>
class DecoderSlack<true, Index> {
 public:
  constexpr DecoderSlack() {}
  Index slack() const { return 0; }
  void set_slack(Index) {}
};

}  // namespace detail

/**
 * Cuts the byte stream at every 0x00 and checks each run between delimiters.
 *
 * The one buffer holds max_frame(MaxPayload) bytes (1.6). A run is COBS-decoded as its bytes
 * arrive: a countdown of the current group's bytes, and the zero a group's code stands for
 * written when the next group's code byte arrives (so the last group's is never written). The
 * CRC is summed as the decoded bytes come, two bytes behind (the last two are the CRC sent),
 * which leaves the delimiter only a comparison and the header to check: the work falls between
 * the bytes on the line, not after the frame's end (crc16() at the delimiter took some 150
 * cycles of an AVR's answer to a service call). A run whose encoded bytes outgrow the buffer
 * (or the lowered limit) is dropped as oversize at its delimiter; the decoded bytes are always
 * fewer than the encoded ones, so nothing is ever written past the buffer, whatever arrives.
 * The payload MTU can be lowered at run time (set_max_payload) but never raised above
 * MaxPayload; FixedMtu: it is always MaxPayload (a board whose every session takes its own
 * MTU), and no byte is checked against a run-time limit.
 *
 * DetectText: a run that fails steps 2-5 and is at least 90 % printable ASCII (TAB, LF, CR
 * included) is reported as FrameError::Text and counted in non_frame_bytes, as a host does;
 * without it such a run counts as its failure (usually cobs). The host's other refinements
 * (splitting a corrupted delimiter, text glued to a frame) are not done: a device MAY skip them.
 */
template <size_t MaxPayload, bool DetectText = true, bool AckInData = true, bool FixedMtu = false>
class FrameDecoder
    : private detail::DecoderSlack<FixedMtu, typename detail::RunIndex<(max_frame(MaxPayload) < 255)>::type> {
 public:
  static const size_t kCapacity = max_frame(MaxPayload);
  /** The type of the run's counts (kOverflow included): a byte when they fit in one. */
  typedef typename detail::RunIndex<(kCapacity < 255)>::type Index;

  /** Every member zero (no slack: the full MTU): a global decoder is in .bss, with
   * no constructor code. */
  constexpr FrameDecoder()
      : frame_{FrameType::BestEffort, Frag::Whole, 0, 0, nullptr, 0, false, 0}, stats_(), run_(0), len_(0),
        crc_(0), text_(), group_(0), zero_(false),
        error_(FrameError::Ok), peer_byte0_(0), buf_() {}

  /** Lowers (or restores) the payload MTU; values above MaxPayload mean MaxPayload. Nothing
   * with FixedMtu (its MTU is always MaxPayload). */
  void set_max_payload(size_t max_payload) {
    this->set_slack(static_cast<Index>(max_payload < MaxPayload ? MaxPayload - max_payload : 0));
  }
  size_t max_payload() const { return MaxPayload - this->slack(); }

  /** Forgets a partial run (after the link reopened). */
  void reset() { clear_run(); }

  /** Consumes one byte. A Frame stays valid (its payload in this buffer) until the next push.
   * Inline: a board calls it from one place, its receive loop, where a call took some 10 of the
   * 176 cycles a byte lasts at 1 Mbaud (26 B of the hello world's flash). */
  Decoded push(uint8_t byte) {
    if (byte != 0) {
      text_.add(byte);
      if (run_ + run_slack() >= kCapacity) {  // the run outgrew max_frame
        run_ = static_cast<Index>(kOverflow);  // above any limit: stays so until the delimiter
      } else {
        ++run_;
        bool keep = true;
        uint8_t group = group_;
        if (group == 0) {  // a code byte: the previous group's zero, and the next group's length
          keep = zero_;
          group = byte;
          zero_ = byte != 0xFF;  // a full group stands for no zero
          byte = 0;
        }
        group_ = static_cast<uint8_t>(group - 1);
        buf_[len_] = byte;  // within the buffer: fewer decoded bytes than run_ <= the limit
        if (keep) {
          // the CRC, two bytes behind: at the delimiter it covers all but the CRC sent
          if (len_ >= kCrcSize) {
            crc_ = crc16_update(len_ == kCrcSize ? kCrcInit : crc_, buf_[len_ - kCrcSize]);
          }
          ++len_;
        }
      }
      return Decoded::Nothing;
    }
    if (run_ == 0) return Decoded::Nothing;  // empty run: nothing, no event
    return end_run();
  }

  /** The frame the last push returned Decoded::Frame for. */
  const Frame& frame() const { return frame_; }
  /** Why the last run was rejected (Ok after a frame). */
  FrameError error() const { return error_; }
  /** The protocol version of the last run rejected as FrameError::Version. */
  uint8_t peer_version() const { return peer_byte0_ >> 6; }
  const DecoderStats& stats() const { return stats_; }
  /** Bytes of the current run held (decoded so far; at most kCapacity). */
  size_t buffered() const { return len_; }

 private:
  /** Below one full COBS group a body decodes from at least one byte more than it has, so a
   * run within max_frame(m) holds at most m payload bytes: step 8 is step 2's (and skipped). */
  static const bool kRunBoundsPayload = max_body(MaxPayload) < kCobsMaxGroup;
  static const size_t kNoLimit = static_cast<size_t>(-1);
  /** run_ of a run that outgrew the limit. */
  static const size_t kOverflow = kCapacity + 1;

  /** kCapacity - the longest run taken, max_frame(max_payload()): the payload's slack when
   * max_frame is payload + 6 (kRunBoundsPayload). */
  size_t run_slack() const {
    return kRunBoundsPayload ? this->slack() : kCapacity - max_frame(max_payload());
  }

  /** The delimiter after a run: checks it, counts it, forgets it. */
  Decoded end_run() {
    FrameError e = check_run();
    const size_t run_bytes = text_.bytes();
    clear_run();
    error_ = e;
    count(e, run_bytes);
    return e == FrameError::Ok ? Decoded::Frame : Decoded::Bad;
  }

  /** Steps 2-9 of 1.6 at the delimiter, in that order. */
  __attribute__((noinline)) FrameError check_run() {
    if (run_ == kOverflow) return text_.text() ? FrameError::Text : FrameError::Oversize;
    // A code that pointed past the end of the run: its group is still waiting for bytes.
    if (group_ != 0) return text_.text() ? FrameError::Text : FrameError::Cobs;
    // parse_body(), with the CRC summed by push()
    FrameError e = FrameError::TooShort;
    if (len_ >= kEnvelope) {
      e = crc_ != wire::get16(buf_ + len_ - kCrcSize)
              ? FrameError::Crc
              : parse_checked(buf_, len_, kRunBoundsPayload ? kNoLimit : max_payload(), &frame_, AckInData);
    }
    if ((e == FrameError::TooShort || e == FrameError::Crc) && text_.text()) {
      return FrameError::Text;
    }
    if (e == FrameError::Version) peer_byte0_ = buf_[0];
    return e;
  }

  void count(FrameError e, size_t run_bytes) {
    if (DetectText && e == FrameError::Text) {
      stats_.non_frame_bytes = static_cast<Counter>(stats_.non_frame_bytes + run_bytes);
    } else {
      ++counter(e);
    }
  }

  /** The counter of a result other than Text (frames for Ok). */
  Counter& counter(FrameError e) {
    // Indexed as Counters from the struct's start (its alignment is a Counter's), not as bytes:
    // a char* cast back to Counter* would claim an alignment the compiler cannot see (-Wcast-align
    // on ARM, where a misaligned 16-bit access faults on a Cortex-M0).
    return reinterpret_cast<Counter*>(&stats_)[counter_offset(e) / sizeof(Counter)];
  }

  void clear_run() {
    run_ = 0;
    len_ = 0;
    text_.clear();
    group_ = 0;
    zero_ = false;
  }

  Frame frame_;
  DecoderStats stats_;
  Index run_;     // encoded bytes of the run taken (at most the limit), or kOverflow
  Index len_;     // decoded bytes in buf_
  uint16_t crc_;  // the CRC of buf_'s first len_ - 2 bytes (once len_ is above 2)
  detail::TextCount<DetectText> text_;
  uint8_t group_;  // data bytes the current COBS group still expects
  bool zero_;      // the current group stands for a zero (written if another group follows)
  FrameError error_;
  uint8_t peer_byte0_;  // header byte 0 of the last run rejected as Version
  uint8_t buf_[kCapacity];  // last: the fuzz tests' guards sit right after it
};

template <size_t MaxPayload, bool DetectText, bool AckInData, bool FixedMtu>
const size_t FrameDecoder<MaxPayload, DetectText, AckInData, FixedMtu>::kCapacity;
template <size_t MaxPayload, bool DetectText, bool AckInData, bool FixedMtu>
const bool FrameDecoder<MaxPayload, DetectText, AckInData, FixedMtu>::kRunBoundsPayload;
template <size_t MaxPayload, bool DetectText, bool AckInData, bool FixedMtu>
const size_t FrameDecoder<MaxPayload, DetectText, AckInData, FixedMtu>::kNoLimit;
template <size_t MaxPayload, bool DetectText, bool AckInData, bool FixedMtu>
const size_t FrameDecoder<MaxPayload, DetectText, AckInData, FixedMtu>::kOverflow;

}  // namespace hwbridge

#endif  // HWBRIDGE_DECODER_H
