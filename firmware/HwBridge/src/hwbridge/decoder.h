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

/** What one byte completed. */
enum class Decoded : uint8_t {
  Nothing,  ///< no run ended, or an empty run (a leading delimiter)
  Frame,    ///< a frame: FrameDecoder::frame()
  Bad,      ///< a rejected run: FrameDecoder::error() says why (counted)
};

/**
 * Cuts the byte stream at every 0x00 and checks each run between delimiters.
 *
 * The one buffer holds max_frame(MaxPayload) bytes (1.6): a run is COBS-decoded in place, and a
 * run that outgrows the buffer is dropped as oversize at its delimiter; nothing is ever written
 * past the buffer, whatever arrives. The payload MTU can be lowered at run time
 * (set_max_payload) but never raised above MaxPayload.
 *
 * DetectText: a run that fails steps 2-5 and is at least 90 % printable ASCII (TAB, LF, CR
 * included) is reported as FrameError::Text and counted in non_frame_bytes, as a host does;
 * without it such a run counts as its failure (usually cobs). The host's other refinements
 * (splitting a corrupted delimiter, text glued to a frame) are not done: a device MAY skip them.
 */
template <size_t MaxPayload, bool DetectText = true>
class FrameDecoder {
 public:
  static const size_t kCapacity = max_frame(MaxPayload);

  /** Every member zero (limits 0 mean the full capacity): a global decoder is in .bss, with
   * no constructor code. */
  constexpr FrameDecoder()
      : frame_{FrameType::BestEffort, Frag::Whole, 0, 0, nullptr, 0}, stats_(), len_(0),
        limit_(0), max_payload_(0), total_(0), printable_(0), overflow_(false),
        error_(FrameError::Ok), peer_version_(0), buf_() {}

  /** Lowers (or restores) the payload MTU; values above MaxPayload mean MaxPayload. */
  void set_max_payload(size_t max_payload) {
    if (max_payload > MaxPayload) max_payload = MaxPayload;
    max_payload_ = max_payload;
    limit_ = max_frame(max_payload);
  }
  size_t max_payload() const { return max_payload_ ? max_payload_ : MaxPayload; }

  /** Forgets a partial run (after the link reopened). */
  void reset() { clear_run(); }

  /** Consumes one byte. A Frame stays valid (its payload in this buffer) until the next push. */
  __attribute__((noinline)) Decoded push(uint8_t byte) {
    if (byte != 0) {
      if (len_ < (limit_ ? limit_ : kCapacity)) {
        buf_[len_++] = byte;
      } else {
        overflow_ = true;
      }
      if (DetectText && total_ != 0xFFFFu) {  // the ratio of the first 65535 bytes
        ++total_;
        if (printable(byte)) ++printable_;
      }
      return Decoded::Nothing;
    }
    if (len_ == 0 && !overflow_) return Decoded::Nothing;  // empty run: nothing, no event
    FrameError e = check_run();
    const size_t run_bytes = DetectText ? total_ : len_;
    clear_run();
    error_ = e;
    if (e == FrameError::Ok) {
      ++stats_.frames;
      return Decoded::Frame;
    }
    count(e, run_bytes);
    return Decoded::Bad;
  }

  /** The frame the last push returned Decoded::Frame for. */
  const Frame& frame() const { return frame_; }
  /** Why the last run was rejected (Ok after a frame). */
  FrameError error() const { return error_; }
  /** The protocol version of the last run rejected as FrameError::Version. */
  uint8_t peer_version() const { return peer_version_; }
  const DecoderStats& stats() const { return stats_; }
  /** Bytes of the current run held (at most kCapacity). */
  size_t buffered() const { return len_; }

 private:
  static bool printable(uint8_t b) { return (b >= 0x20 && b <= 0x7E) || b == 9 || b == 10 || b == 13; }

  bool looks_like_text() const {
    return DetectText && total_ > 0 &&
           static_cast<uint32_t>(printable_) * 10u >= static_cast<uint32_t>(total_) * 9u;
  }

  __attribute__((noinline)) FrameError check_run() {
    if (overflow_) return looks_like_text() ? FrameError::Text : FrameError::Oversize;
    size_t body_len = 0;
    if (!cobs_decode(buf_, len_, buf_, &body_len)) {
      return looks_like_text() ? FrameError::Text : FrameError::Cobs;
    }
    FrameError e = parse_body(buf_, body_len, max_payload(), &frame_);
    if ((e == FrameError::TooShort || e == FrameError::Crc) && looks_like_text()) {
      return FrameError::Text;
    }
    if (e == FrameError::Version) peer_version_ = buf_[0] >> 6;
    return e;
  }

  void count(FrameError e, size_t run_bytes) {
    switch (e) {
      case FrameError::Crc: ++stats_.crc_errors; break;
      case FrameError::Cobs: ++stats_.cobs_errors; break;
      case FrameError::TooShort: ++stats_.too_short; break;
      case FrameError::Version: ++stats_.version_errors; break;
      case FrameError::ReservedType: ++stats_.reserved_type; break;
      case FrameError::Oversize: ++stats_.oversize; break;
      case FrameError::Text: stats_.non_frame_bytes = static_cast<Counter>(stats_.non_frame_bytes + run_bytes); break;
      case FrameError::Ok: break;
    }
  }

  void clear_run() {
    len_ = 0;
    total_ = 0;
    printable_ = 0;
    overflow_ = false;
  }

  Frame frame_;
  DecoderStats stats_;
  size_t len_;
  size_t limit_;
  size_t max_payload_;
  uint16_t total_;      // bytes of the run, also past the buffer (for text detection)
  uint16_t printable_;  // printable bytes among them
  bool overflow_;
  FrameError error_;
  uint8_t peer_version_;
  uint8_t buf_[kCapacity];  // last: the fuzz tests' guards sit right after it
};

template <size_t MaxPayload, bool DetectText>
const size_t FrameDecoder<MaxPayload, DetectText>::kCapacity;

}  // namespace hwbridge

#endif  // HWBRIDGE_DECODER_H
