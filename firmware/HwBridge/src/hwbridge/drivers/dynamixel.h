// Dynamixel servos on a half-duplex UART with a direction pin (Protocol 1.0 and 2.0).
//
// Pairs with the `dynamixel` board-device plugin (a servo the board drives: it publishes
// sensor_msgs/JointState and takes std_msgs/Float64 goal positions) and follows the packet
// formats of devices/dynamixel (DEVICES.md): Protocol 2.0 `FF FF FD 00 ID LEN_L LEN_H INST
// params CRC_L CRC_H` with byte stuffing and CRC-16 (polynomial 0x8005), Protocol 1.0 `FF FF ID
// LEN INST params CHK`.
//
//   hwbridge::drivers::DynamixelBus<HardwareSerial> bus(Serial1, 2, 2);  // UART, DIR pin, protocol
//   bus.begin(57600);
//   bus.write_u8(1, 64, 1);                       // Torque Enable (X series)
//   int32_t ticks; if (bus.read_i32(1, 132, ticks)) ...   // Present Position
//
// The direction pin is high while the board transmits (a 74LS241 / 74HC126 buffer's enable) and
// low to receive; transmit() waits for the UART to finish (Serial.flush()) before turning it.
// A transaction is started (start_read(), start_write(), send()) then poll()ed until it is done
// or timed out, so loop() need not wait; read()/write() do both in one call, waiting at most
// timeout_us (default 10 ms). On a single wire without a buffer the board hears its own packet:
// set echo(true) and it is skipped.
#ifndef HWBRIDGE_DRIVERS_DYNAMIXEL_H
#define HWBRIDGE_DRIVERS_DYNAMIXEL_H

#include "arduino_api.h"
#include <stddef.h>
#include <stdint.h>

namespace hwbridge {
namespace drivers {
namespace dxl {

const uint8_t kPing = 0x01;
const uint8_t kRead = 0x02;
const uint8_t kWrite = 0x03;
const uint8_t kStatus = 0x55;  // Protocol 2.0 status instruction
const uint8_t kBroadcast = 0xFE;

/** CRC-16 of Protocol 2.0: polynomial 0x8005, not reflected, init 0 (or a running value). */
inline uint16_t crc16(const uint8_t* data, size_t n, uint16_t crc = 0) {
  for (size_t i = 0; i < n; ++i) {
    crc = static_cast<uint16_t>(crc ^ (static_cast<uint16_t>(data[i]) << 8));
    for (uint8_t bit = 0; bit < 8; ++bit) {
      crc = (crc & 0x8000U) ? static_cast<uint16_t>((crc << 1) ^ 0x8005U)
                            : static_cast<uint16_t>(crc << 1);
    }
  }
  return crc;
}

/** An instruction packet into out (cap bytes): its length, or 0 if it does not fit or the
    protocol is neither 1 nor 2. Protocol 2.0 parameters are byte-stuffed. */
inline size_t build_packet(uint8_t protocol, uint8_t id, uint8_t instruction,
                           const uint8_t* params, size_t n, uint8_t* out, size_t cap) {
  if (protocol == 1) {
    if (n + 6 > cap || n > 253) return 0;
    out[0] = 0xFF;
    out[1] = 0xFF;
    out[2] = id;
    out[3] = static_cast<uint8_t>(n + 2);
    out[4] = instruction;
    uint8_t sum = static_cast<uint8_t>(id + out[3] + instruction);
    for (size_t i = 0; i < n; ++i) {
      out[5 + i] = params[i];
      sum = static_cast<uint8_t>(sum + params[i]);
    }
    out[5 + n] = static_cast<uint8_t>(~sum);
    return n + 6;
  }
  if (protocol != 2) return 0;
  if (cap < 10) return 0;
  out[0] = 0xFF;
  out[1] = 0xFF;
  out[2] = 0xFD;
  out[3] = 0x00;
  out[4] = id;
  size_t at = 7;
  uint8_t run = 0;  // how much of FF FF FD the body has just matched
  for (size_t i = 0; i <= n; ++i) {
    uint8_t b = i == 0 ? instruction : params[i - 1];
    if (at + 1 > cap - 2) return 0;
    out[at++] = b;
    if (b == 0xFF) {
      run = run < 2 ? static_cast<uint8_t>(run + 1) : 2;
    } else if (b == 0xFD && run == 2) {
      if (at + 1 > cap - 2) return 0;
      out[at++] = 0xFD;
      run = 0;
    } else {
      run = 0;
    }
  }
  size_t length = at - 7 + 2;  // instruction, stuffed parameters, CRC
  out[5] = static_cast<uint8_t>(length & 0xFF);
  out[6] = static_cast<uint8_t>(length >> 8);
  uint16_t crc = crc16(out, at);
  out[at++] = static_cast<uint8_t>(crc & 0xFF);
  out[at++] = static_cast<uint8_t>(crc >> 8);
  return at;
}

/** Status packets out of a byte stream, one byte at a time (bounded: parameters beyond
    MaxParams make the packet count as bad). */
template <size_t MaxParams>
class StatusParser {
 public:
  explicit StatusParser(uint8_t protocol = 2) : protocol_(protocol) {}
  void set_protocol(uint8_t protocol) {
    protocol_ = protocol;
    reset();
  }
  void reset() {
    at_ = 0;
    have_ = false;
  }
  /** One byte in: true when it completes a valid status packet (id(), error(), params()). */
  bool feed(uint8_t b) {
    have_ = false;
    if (protocol_ == 1) return feed1(b);
    return feed2(b);
  }
  uint8_t id() const { return id_; }
  uint8_t error() const { return error_; }
  const uint8_t* params() const { return params_; }
  size_t size() const { return size_; }
  /** Packets with a bad checksum, a bad length or too many parameters. */
  uint16_t bad() const { return bad_; }

 private:
  bool fail() {
    ++bad_;
    at_ = 0;
    return false;
  }
  bool feed1(uint8_t b) {
    // FF FF ID LEN ERR params CHK
    if (at_ < 2) {
      at_ = b == 0xFF ? static_cast<uint8_t>(at_ + 1) : 0;
      return false;
    }
    if (at_ == 2) {
      if (b == 0xFF) return false;  // a third FF: still the header
      id_ = b;
      sum_ = b;
      ++at_;
      return false;
    }
    if (at_ == 3) {
      if (b < 2 || static_cast<size_t>(b - 2) > MaxParams) return fail();
      length_ = b;
      sum_ = static_cast<uint8_t>(sum_ + b);
      size_ = 0;
      ++at_;
      return false;
    }
    if (at_ == 4) {
      error_ = b;
      sum_ = static_cast<uint8_t>(sum_ + b);
      ++at_;
      return false;
    }
    if (size_ + 2 < length_) {
      params_[size_++] = b;
      sum_ = static_cast<uint8_t>(sum_ + b);
      return false;
    }
    at_ = 0;
    if (static_cast<uint8_t>(~sum_) != b) return fail();
    have_ = true;
    return true;
  }
  bool feed2(uint8_t b) {
    // FF FF FD 00 ID LEN_L LEN_H 55 ERR params CRC_L CRC_H
    static const uint8_t kHeader[4] = {0xFF, 0xFF, 0xFD, 0x00};
    if (at_ < 4) {
      if (b == kHeader[at_]) {
        if (at_ == 0) crc_ = 0;
        crc_ = crc16(&b, 1, crc_);
        ++at_;
      } else if (b == 0xFF) {
        // FF FF FF ...: the header may start one byte later.
        at_ = at_ == 2 ? 2 : 1;
        crc_ = crc16(kHeader, at_);
      } else {
        at_ = 0;
      }
      return false;
    }
    if (at_ == 4) {
      id_ = b;
    } else if (at_ == 5) {
      length_ = b;
    } else if (at_ == 6) {
      length_ = static_cast<uint16_t>(length_ | (static_cast<uint16_t>(b) << 8));
      if (length_ < 4 || length_ > 2 * MaxParams + 4) return fail();
      remaining_ = static_cast<uint16_t>(length_ - 2);  // instruction, error, stuffed params
      size_ = 0;
      run_ = 0;
    } else if (remaining_ > 0) {
      --remaining_;
      uint16_t index = static_cast<uint16_t>(length_ - 2 - remaining_ - 1);
      if (index == 0) {
        if (b != kStatus) return fail();
      } else if (index == 1) {
        error_ = b;
      } else if (b == 0xFD && run_ == 3) {
        run_ = 0;  // the stuffed FD: dropped
      } else {
        if (run_ == 3) run_ = 0;
        if (size_ >= MaxParams) return fail();
        params_[size_++] = b;
        if (b == 0xFF) {
          run_ = run_ < 2 ? static_cast<uint8_t>(run_ + 1) : 2;
        } else if (b == 0xFD && run_ == 2) {
          run_ = 3;
        } else {
          run_ = 0;
        }
      }
    } else if (at_ == kCrcLow) {
      crc_low_ = b;
      ++at_;
      return false;
    } else {
      at_ = 0;
      uint16_t got = static_cast<uint16_t>(crc_low_ | (static_cast<uint16_t>(b) << 8));
      if (got != crc_) return fail();
      have_ = true;
      return true;
    }
    crc_ = crc16(&b, 1, crc_);
    if (at_ < 7) {
      ++at_;
    } else if (remaining_ == 0) {
      at_ = kCrcLow;
    }
    return false;
  }

  static const uint8_t kCrcLow = 200;  // parser position: the CRC's low byte is next
  uint8_t protocol_;
  uint8_t at_ = 0;
  uint8_t id_ = 0;
  uint8_t error_ = 0;
  uint8_t sum_ = 0;
  uint8_t run_ = 0;
  uint8_t crc_low_ = 0;
  bool have_ = false;
  uint16_t length_ = 0;
  uint16_t remaining_ = 0;
  uint16_t crc_ = 0;
  uint16_t bad_ = 0;
  size_t size_ = 0;
  uint8_t params_[MaxParams > 0 ? MaxParams : 1];
};

/** Joint angle of an X-series position (tick 2048 = 0, 4096 ticks a turn) in radians. */
inline float x_ticks_to_radians(int32_t ticks) {
  return static_cast<float>(ticks - 2048) * (6.2831853f / 4096.0f);
}
inline int32_t x_radians_to_ticks(float radians) {
  float t = radians / (6.2831853f / 4096.0f) + 2048.0f;
  return static_cast<int32_t>(t >= 0.0f ? t + 0.5f : t - 0.5f);
}
/** AX-12A (Protocol 1.0): tick 512 = 0, 300 degrees over 1024 ticks. */
inline float ax_ticks_to_radians(int32_t ticks) {
  return static_cast<float>(ticks - 512) * (5.2359878f / 1024.0f);
}
inline int32_t ax_radians_to_ticks(float radians) {
  float t = radians / (5.2359878f / 1024.0f) + 512.0f;
  return static_cast<int32_t>(t >= 0.0f ? t + 0.5f : t - 0.5f);
}

}  // namespace dxl

/** Where a transaction is. */
enum DxlResult : uint8_t { kDxlPending = 0, kDxlDone = 1, kDxlTimeout = 2, kDxlIdle = 3 };

/** A Dynamixel bus on a UART (SerialT: HardwareSerial or anything with begin/write/flush/
    available/read) with a direction pin (0xFF: none, e.g. a board with a buffer that turns by
    itself). MaxParams bounds the parameters of one packet either way. */
template <class SerialT, size_t MaxParams = 16>
class DynamixelBus {
 public:
  static const uint8_t kNoPin = 0xFF;

  DynamixelBus(SerialT& serial, uint8_t dir_pin, uint8_t protocol = 2)
      : serial_(serial), dir_pin_(dir_pin), protocol_(protocol), parser_(protocol) {}

  void begin(uint32_t baud) {
    if (dir_pin_ != kNoPin) {
      pinMode(dir_pin_, OUTPUT);
      digitalWrite(dir_pin_, LOW);
    }
    serial_.begin(baud);
  }
  uint8_t protocol() const { return protocol_; }
  /** The board hears its own packets (one wire, no buffer): skip that many bytes after each. */
  void echo(bool on) { echo_ = on; }
  void set_timeout_us(uint32_t timeout_us) { timeout_us_ = timeout_us; }

  /** Start a transaction: the packet goes out now; poll() gives the status. A broadcast (other
      than PING) expects no status and is done at once. False if the packet does not fit. */
  bool send(uint8_t id, uint8_t instruction, const uint8_t* params, size_t n) {
    uint8_t packet[kPacketCap];
    size_t size = dxl::build_packet(protocol_, id, instruction, params, n, packet, sizeof packet);
    if (size == 0) return false;
    while (serial_.available() > 0) serial_.read();  // stale bytes
    if (dir_pin_ != kNoPin) digitalWrite(dir_pin_, HIGH);
    serial_.write(packet, size);
    serial_.flush();
    if (dir_pin_ != kNoPin) digitalWrite(dir_pin_, LOW);
    skip_ = echo_ ? size : 0;
    parser_.reset();
    id_ = id;
    sent_us_ = micros();
    state_ = (id == dxl::kBroadcast && instruction != dxl::kPing) ? kDxlDone : kDxlPending;
    return true;
  }
  /** Progress of the transaction: kDxlDone when the servo's status came (status_error(),
      status_params()), kDxlTimeout when it did not within the timeout. */
  DxlResult poll() {
    while (state_ == kDxlPending && serial_.available() > 0) {
      int c = serial_.read();
      if (c < 0) break;
      if (skip_ > 0) {
        --skip_;
        continue;
      }
      if (parser_.feed(static_cast<uint8_t>(c)) && parser_.id() == id_) state_ = kDxlDone;
    }
    if (state_ == kDxlPending && static_cast<uint32_t>(micros() - sent_us_) > timeout_us_) {
      state_ = kDxlTimeout;
      ++timeouts_;
    }
    return state_;
  }
  /** The last status's error byte and parameters. */
  uint8_t status_error() const { return parser_.error(); }
  const uint8_t* status_params() const { return parser_.params(); }
  size_t status_size() const { return parser_.size(); }
  uint16_t timeouts() const { return timeouts_; }
  uint16_t bad_packets() const { return parser_.bad(); }

  /** Waits for the transaction (at most the timeout): true when the status came. */
  bool wait() {
    DxlResult r;
    do {
      r = poll();
    } while (r == kDxlPending);
    return r == kDxlDone;
  }

  bool ping(uint8_t id) { return send(id, dxl::kPing, nullptr, 0) && wait(); }

  // Non-blocking: start a READ or WRITE; poll() until it is done (status_params() then hold
  // the bytes read) or timed out.
  bool start_read(uint8_t id, uint16_t address, uint8_t n) {
    uint8_t params[4];
    size_t count;
    if (protocol_ == 1) {
      params[0] = static_cast<uint8_t>(address);
      params[1] = n;
      count = 2;
    } else {
      params[0] = static_cast<uint8_t>(address & 0xFF);
      params[1] = static_cast<uint8_t>(address >> 8);
      params[2] = n;
      params[3] = 0;
      count = 4;
    }
    return send(id, dxl::kRead, params, count);
  }
  bool start_write(uint8_t id, uint16_t address, const uint8_t* data, uint8_t n) {
    uint8_t params[MaxParams];
    size_t head = protocol_ == 1 ? 1 : 2;
    if (n + head > MaxParams) return false;
    params[0] = static_cast<uint8_t>(address & 0xFF);
    if (head == 2) params[1] = static_cast<uint8_t>(address >> 8);
    for (uint8_t i = 0; i < n; ++i) params[head + i] = data[i];
    return send(id, dxl::kWrite, params, head + n);
  }
  /** A little-endian value of `size` bytes (1, 2 or 4). */
  bool start_write_int(uint8_t id, uint16_t address, int32_t value, uint8_t size) {
    uint8_t data[4];
    uint32_t v = static_cast<uint32_t>(value);
    for (uint8_t i = 0; i < 4; ++i) data[i] = static_cast<uint8_t>(v >> (8 * i));
    return size <= 4 && start_write(id, address, data, size);
  }
  /** The last status's first `size` parameters as a little-endian signed value (1, 2 or 4
      bytes, sign-extended); false if the status has not that many. */
  bool status_int(int32_t& value, uint8_t size) const {
    if (size == 0 || size > 4 || parser_.size() != size) return false;
    const uint8_t* data = parser_.params();
    uint32_t v = 0;
    for (uint8_t i = 0; i < size; ++i) v |= static_cast<uint32_t>(data[i]) << (8 * i);
    if (size < 4 && (data[size - 1] & 0x80)) v |= static_cast<uint32_t>(0xFFFFFFFFUL << (8 * size));
    value = static_cast<int32_t>(v);
    return true;
  }

  // Blocking: the same, waiting at most the timeout.
  /** Reads n bytes of the control table from address into out. */
  bool read(uint8_t id, uint16_t address, uint8_t* out, uint8_t n) {
    if (!start_read(id, address, n) || !wait() || parser_.size() != n) return false;
    for (uint8_t i = 0; i < n; ++i) out[i] = parser_.params()[i];
    return true;
  }
  /** Writes n bytes from data to the control table at address (status awaited unless id is
      the broadcast id). */
  bool write(uint8_t id, uint16_t address, const uint8_t* data, uint8_t n) {
    return start_write(id, address, data, n) && wait();
  }
  bool write_u8(uint8_t id, uint16_t address, uint8_t value) {
    return write(id, address, &value, 1);
  }
  bool write_int(uint8_t id, uint16_t address, int32_t value, uint8_t size) {
    return start_write_int(id, address, value, size) && wait();
  }
  /** A little-endian signed value of `size` bytes (1, 2 or 4), sign-extended. */
  bool read_int(uint8_t id, uint16_t address, int32_t& value, uint8_t size) {
    return size > 0 && size <= 4 && start_read(id, address, size) && wait() &&
           status_int(value, size);
  }

 private:
  static const size_t kPacketCap = 10 + MaxParams + MaxParams / 3 + 2;

  SerialT& serial_;
  uint8_t dir_pin_;
  uint8_t protocol_;
  bool echo_ = false;
  uint8_t id_ = 0;
  DxlResult state_ = kDxlIdle;
  size_t skip_ = 0;
  uint32_t sent_us_ = 0;
  uint32_t timeout_us_ = 10000;
  uint16_t timeouts_ = 0;
  dxl::StatusParser<MaxParams> parser_;
};

}  // namespace drivers
}  // namespace hwbridge

#endif  // HWBRIDGE_DRIVERS_DYNAMIXEL_H
