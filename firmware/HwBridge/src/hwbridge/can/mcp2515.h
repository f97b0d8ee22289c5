// A Driver (see can_hardware.h) for the Microchip MCP2515 CAN controller on SPI, register level:
// reset, bit timing computed for the crystal (8 or 16 MHz, 125k..1M bit/s), extended ids, both
// receive buffers with the chip's acceptance filters set for this node (RXB0: transfers to it,
// rolling over into RXB1; RXB1 also: NODE messages such as claims, to anyone), and two
// transmit buffers by queue class: ACK and claim frames (class 0..3) in TXB1 at the
// highest TXP, data in TXB0 at a lower one; each buffer sends its frames in order, one at a time,
// so a transfer's frames never overtake each other. A frame not sent within the send timeout
// (no other node acknowledging, bus off) is aborted and the send fails.
//
// Mcp2515T<Port> talks through Port: select(), deselect(), uint8_t transfer(uint8_t),
// uint32_t micros(), uint32_t seed(). On Arduino, Mcp2515 is Mcp2515T<ArduinoSpiPort> (the SPI
// library, mode 0, 8 MHz at most; the chip-select pin given to port().setPin()): include <SPI.h>
// before this header, as examples/CanNode does.
#ifndef HWBRIDGE_CAN_MCP2515_H
#define HWBRIDGE_CAN_MCP2515_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "transport.h"

namespace hwbridge {
namespace can {

namespace mcp {
// SPI instructions
static const uint8_t kReset = 0xC0;
static const uint8_t kRead = 0x03;
static const uint8_t kWrite = 0x02;
static const uint8_t kBitModify = 0x05;
static const uint8_t kReadStatus = 0xA0;
static const uint8_t kLoadTx = 0x40;     // | 0 (TXB0 from SIDH), 2 (TXB1), 4 (TXB2)
static const uint8_t kRts = 0x80;        // | 1 << buffer
static const uint8_t kReadRx = 0x90;     // | 0 (RXB0 from SIDH), 4 (RXB1 from SIDH)
// Registers
static const uint8_t kCanStat = 0x0E;
static const uint8_t kCanCtrl = 0x0F;
static const uint8_t kTec = 0x1C;
static const uint8_t kRec = 0x1D;
static const uint8_t kCnf3 = 0x28;
static const uint8_t kCnf2 = 0x29;
static const uint8_t kCnf1 = 0x2A;
static const uint8_t kCanIntE = 0x2B;
static const uint8_t kCanIntF = 0x2C;
static const uint8_t kEflg = 0x2D;
static const uint8_t kTxb0Ctrl = 0x30;
static const uint8_t kTxb1Ctrl = 0x40;
static const uint8_t kRxb0Ctrl = 0x60;
static const uint8_t kRxb1Ctrl = 0x70;
static const uint8_t kRxf0 = 0x00;  // RXF0..2 at 0x00, 0x04, 0x08; RXF3..5 at 0x10, 0x14, 0x18
static const uint8_t kRxf3 = 0x10;
static const uint8_t kRxm0 = 0x20;  // RXM0 at 0x20, RXM1 at 0x24
// Bits
static const uint8_t kModeMask = 0xE0;
static const uint8_t kModeNormal = 0x00;
static const uint8_t kModeConfig = 0x80;
static const uint8_t kTxReq = 0x08;
static const uint8_t kExide = 0x08;  // SIDL: extended identifier
static const uint8_t kRtr = 0x40;    // DLC: remote frame (extended frames)
static const uint8_t kSrr = 0x10;    // RX SIDL: remote request (standard frames)
static const uint8_t kRx0If = 0x01;
static const uint8_t kRx1If = 0x02;
static const uint8_t kErrIf = 0x20;
static const uint8_t kMerrF = 0x80;
static const uint8_t kRx0Ovr = 0x40;
static const uint8_t kRx1Ovr = 0x80;
static const uint8_t kTxBo = 0x20;
}  // namespace mcp

/** CNF1..CNF3 of a bit rate. */
struct BitTiming {
  uint8_t cnf1;
  uint8_t cnf2;
  uint8_t cnf3;
};

/**
 * The bit timing of bitrate with a crystal of crystal_hz: the smallest prescaler giving a whole
 * number of 4..25 time quanta a bit, the sample point near 75 %, SJW 1, one sample. False when
 * the rate cannot be made exactly.
 */
inline bool mcp2515_timing(uint32_t crystal_hz, uint32_t bitrate, BitTiming* out) {
  if (bitrate == 0) return false;
  for (uint8_t brp = 0; brp < 64; ++brp) {
    const uint32_t div = 2UL * (brp + 1UL) * bitrate;
    if (crystal_hz % div != 0) continue;
    const uint32_t ntq = crystal_hz / div;
    if (ntq > 25) continue;
    if (ntq < 4) return false;
    uint8_t ps2;
    if (ntq < 5) {
      ps2 = 1;  // 4 quanta (8 MHz at 1 Mbit/s): below the data sheet's minimum, common practice
    } else {
      ps2 = static_cast<uint8_t>((ntq + 2) / 4);
      if (ps2 < 2) ps2 = 2;
      if (ps2 > 8) ps2 = 8;
    }
    const uint8_t rest = static_cast<uint8_t>(ntq - 1 - ps2);  // propagation + phase 1
    uint8_t ps1 = static_cast<uint8_t>(rest / 2);
    if (ps1 > 8) ps1 = 8;
    uint8_t prop = static_cast<uint8_t>(rest - ps1);
    if (prop > 8) {
      ps1 = static_cast<uint8_t>(ps1 + prop - 8);
      prop = 8;
    }
    if (ps1 < 1 || ps1 > 8 || prop < 1) return false;
    out->cnf1 = brp;  // SJW 1
    out->cnf2 = static_cast<uint8_t>(0x80 | (ps1 - 1) << 3 | (prop - 1));  // BTLMODE: PS2 in CNF3
    out->cnf3 = static_cast<uint8_t>(ps2 - 1);
    return true;
  }
  return false;
}

/** The four id registers (SIDH, SIDL, EID8, EID0) of a 29-bit id; with exide, EXIDE set (a
 * filter that matches extended frames only; masks have no such bit). */
inline void mcp2515_id_regs(uint32_t id, bool exide, uint8_t* r) {
  r[0] = static_cast<uint8_t>(id >> 21);
  r[1] = static_cast<uint8_t>(((id >> 13) & 0xE0) | (exide ? mcp::kExide : 0) | ((id >> 16) & 0x03));
  r[2] = static_cast<uint8_t>(id >> 8);
  r[3] = static_cast<uint8_t>(id);
}

/** Counters of an Mcp2515T (they only grow). */
struct Mcp2515Stats {
  uint32_t rx_frames;
  uint32_t tx_frames;
  uint32_t tx_timeouts;   ///< frames aborted: not sent within the send timeout
  uint32_t rx_overflow;   ///< frames the chip lost, both receive buffers full (RXnOVR)
  uint32_t remote;        ///< remote frames received (not ours, dropped)
  uint32_t bus_off;       ///< times the chip was seen bus off
  uint32_t errors;        ///< error interrupts (ERRIF, MERRF)
};

template <class Port>
class Mcp2515T {
 public:
  // all zero (the defaults: 16 MHz, 500 kbit/s, 10 ms): a global node lies in .bss
  constexpr Mcp2515T() : stats(), port_(), crystal_(0), bitrate_(0), timeout_us_(0), ok_(false) {}

  /** The bus's bit rate and the chip's crystal (before begin()). */
  void configure(uint32_t bitrate, uint32_t crystal_hz = 16000000UL) {
    bitrate_ = bitrate;
    crystal_ = crystal_hz;
  }
  /** How long send() waits for a transmit buffer before aborting its frame (default 10 ms). */
  void setSendTimeout(uint32_t us) { timeout_us_ = us; }
  Port& port() { return port_; }

  /**
   * Resets the chip, sets the bit timing and receive buffers, enters normal mode. With a node id
   * (1..127) the acceptance filters let through only extended frames this node needs (CAN.md
   * 11), so a busy bus's other traffic never reaches the SPI bus; with 0 every frame is received
   * (the transport filters). RXB0 (RXM0: format bit, direction bit, node field), rolling over
   * into RXB1: format 2 to this node (RXF0), format 1 from the host (RXF1: to this node, and to
   * others, only while a format-1 host is on the bus). RXB1 (RXM1: id bits 15..7, the format-1
   * destination field): format-2 frames from the host whose frag is 0 and seq bits 7..5 are 001
   * (RXF2: the claims of a host that takes chains, CAN.md 12, bit 11 set) or 000 (RXF5: a
   * version-2 host's claims), with a quarter or so of its traffic to other boards, format 1 to
   * this node (RXF3), format 1 to the host (RXF4: format-1 claims). A format-2 board claiming
   * this node id is not let through: the host reports that conflict (CAN.md 2).
   */
  bool begin(uint8_t node = 0) {
    ok_ = false;
    BitTiming t;
    if (!mcp2515_timing(crystal_ ? crystal_ : 16000000UL, bitrate_ ? bitrate_ : 500000UL, &t)) {
      return false;
    }
    port_.begin();
    port_.select();
    port_.transfer(mcp::kReset);
    port_.deselect();
    if (!waitMode(mcp::kModeConfig)) return false;
    const uint8_t cnf[3] = {t.cnf3, t.cnf2, t.cnf1};
    writeRegs(mcp::kCnf3, cnf, 3);
    writeReg(mcp::kCanIntE, 0);
    if (node != 0 && node < 128) {
      uint8_t r[12];
      mcp2515_id_regs(kFormat2Bit | kToHostBit | 0x7F, false, r);  // RXM0
      mcp2515_id_regs(0xFF80UL, false, r + 4);                    // RXM1: id bits 15..7
      writeRegs(mcp::kRxm0, r, 8);
      mcp2515_id_regs(kFormat2Bit | node, true, r);           // RXF0: format 2 to us
      mcp2515_id_regs(0, true, r + 4);                         // RXF1: format 1 from the host
      mcp2515_id_regs(kFormat2Bit | kClaimChains, true, r + 8);  // RXF2: claims, chains
      writeRegs(mcp::kRxf0, r, 12);
      mcp2515_id_regs(encode_id(0, 0, 0, node, 0), true, r);  // RXF3: format 1 to us
      mcp2515_id_regs(0, true, r + 4);                         // RXF4: format 1 to the host
      mcp2515_id_regs(kFormat2Bit, true, r + 8);               // RXF5: version-2 claims
      writeRegs(mcp::kRxf3, r, 12);
      writeReg(mcp::kRxb0Ctrl, 0x04);  // filters on, roll over into RXB1
      writeReg(mcp::kRxb1Ctrl, 0x00);
    } else {
      writeReg(mcp::kRxb0Ctrl, 0x64);  // any frame (filters off), roll over into RXB1
      writeReg(mcp::kRxb1Ctrl, 0x60);
    }
    writeReg(mcp::kTxb0Ctrl, 0x01);  // TXP 1: data
    writeReg(mcp::kTxb1Ctrl, 0x03);  // TXP 3: ACK, control, claims
    writeReg(mcp::kCanIntF, 0);
    modify(mcp::kCanCtrl, mcp::kModeMask, mcp::kModeNormal);
    ok_ = waitMode(mcp::kModeNormal);
    return ok_;
  }

  bool receive(Frame* f) {
    if (!ok_) return false;
    for (;;) {
      const uint8_t status = readStatus();
      if (status & (mcp::kRx0If | mcp::kRx1If)) {
        if (readRx(status & mcp::kRx0If ? 0 : 4, f)) return true;
        continue;  // a remote frame: counted, next one
      }
      checkErrors();
      return false;
    }
  }

  bool send(const Frame& f, uint8_t priority) {
    if (!ok_) return false;
    const uint8_t buffer = priority <= kPriorityNode ? 1 : 0;
    const uint8_t ctrl = buffer ? mcp::kTxb1Ctrl : mcp::kTxb0Ctrl;
    const uint32_t start = port_.micros();
    while (readReg(ctrl) & mcp::kTxReq) {
      if (port_.micros() - start >= (timeout_us_ ? timeout_us_ : 10000UL)) {
        modify(ctrl, mcp::kTxReq, 0);  // abort the frame that does not go
        ++stats.tx_timeouts;
        checkErrors();
        return false;
      }
    }
    uint8_t regs[13];
    if (f.extended) {
      mcp2515_id_regs(f.id, true, regs);
    } else {
      regs[0] = static_cast<uint8_t>(f.id >> 3);
      regs[1] = static_cast<uint8_t>((f.id & 0x07) << 5);
      regs[2] = 0;
      regs[3] = 0;
    }
    const uint8_t len = f.len > 8 ? 8 : f.len;
    regs[4] = len;
    for (uint8_t i = 0; i < len; ++i) regs[5 + i] = f.data[i];
    port_.select();
    port_.transfer(static_cast<uint8_t>(mcp::kLoadTx | (buffer << 1)));
    for (uint8_t i = 0; i < 5 + len; ++i) port_.transfer(regs[i]);
    port_.deselect();
    port_.select();
    port_.transfer(static_cast<uint8_t>(mcp::kRts | (1 << buffer)));
    port_.deselect();
    ++stats.tx_frames;
    return true;
  }

  uint32_t micros() { return port_.micros(); }
  uint32_t seed() { return port_.seed() ^ (static_cast<uint32_t>(readReg(mcp::kTec)) << 8); }

  /** The transmit and receive error counters (TEC, REC). */
  uint8_t txErrors() { return readReg(mcp::kTec); }
  uint8_t rxErrors() { return readReg(mcp::kRec); }

  Mcp2515Stats stats;

 private:
  bool waitMode(uint8_t mode) {
    const uint32_t start = port_.micros();
    while ((readReg(mcp::kCanStat) & mcp::kModeMask) != mode) {
      if (port_.micros() - start >= 20000UL) return false;
    }
    return true;
  }
  uint8_t readReg(uint8_t addr) {
    port_.select();
    port_.transfer(mcp::kRead);
    port_.transfer(addr);
    const uint8_t v = port_.transfer(0);
    port_.deselect();
    return v;
  }
  void writeRegs(uint8_t addr, const uint8_t* v, uint8_t n) {
    port_.select();
    port_.transfer(mcp::kWrite);
    port_.transfer(addr);
    for (uint8_t i = 0; i < n; ++i) port_.transfer(v[i]);
    port_.deselect();
  }
  void writeReg(uint8_t addr, uint8_t v) { writeRegs(addr, &v, 1); }
  void modify(uint8_t addr, uint8_t mask, uint8_t v) {
    port_.select();
    port_.transfer(mcp::kBitModify);
    port_.transfer(addr);
    port_.transfer(mask);
    port_.transfer(v);
    port_.deselect();
  }
  uint8_t readStatus() {
    port_.select();
    port_.transfer(mcp::kReadStatus);
    const uint8_t v = port_.transfer(0);
    port_.deselect();
    return v;
  }
  // Reads RXB0 (at 0) or RXB1 (at 4) from SIDH; the chip clears its RXnIF when CS rises.
  bool readRx(uint8_t at, Frame* f) {
    uint8_t regs[13];
    port_.select();
    port_.transfer(static_cast<uint8_t>(mcp::kReadRx | at));
    for (uint8_t i = 0; i < 13; ++i) regs[i] = port_.transfer(0);
    port_.deselect();
    const uint8_t sidl = regs[1];
    const uint32_t sid = (static_cast<uint32_t>(regs[0]) << 3) | (sidl >> 5);
    const uint8_t dlc = regs[4];
    if (sidl & mcp::kExide) {
      f->extended = true;
      f->id = (sid << 18) | (static_cast<uint32_t>(sidl & 0x03) << 16) |
              (static_cast<uint32_t>(regs[2]) << 8) | regs[3];
      if (dlc & mcp::kRtr) {
        ++stats.remote;
        return false;
      }
    } else {
      f->extended = false;
      f->id = sid;
      if (sidl & mcp::kSrr) {
        ++stats.remote;
        return false;
      }
    }
    f->len = static_cast<uint8_t>((dlc & 0x0F) > 8 ? 8 : (dlc & 0x0F));
    for (uint8_t i = 0; i < f->len; ++i) f->data[i] = regs[5 + i];
    ++stats.rx_frames;
    return true;
  }
  void checkErrors() {
    const uint8_t flags = readReg(mcp::kCanIntF);
    if (!(flags & (mcp::kErrIf | mcp::kMerrF))) return;
    ++stats.errors;
    const uint8_t eflg = readReg(mcp::kEflg);
    if (eflg & (mcp::kRx0Ovr | mcp::kRx1Ovr)) {
      ++stats.rx_overflow;
      modify(mcp::kEflg, mcp::kRx0Ovr | mcp::kRx1Ovr, 0);
    }
    if (eflg & mcp::kTxBo) ++stats.bus_off;  // the chip recovers by itself after 128 x 11 bits
    modify(mcp::kCanIntF, mcp::kErrIf | mcp::kMerrF, 0);
  }

  Port port_;
  uint32_t crystal_;
  uint32_t bitrate_;
  uint32_t timeout_us_;
  bool ok_;
};

}  // namespace can
}  // namespace hwbridge

// Mcp2515 (the chip on the Arduino SPI library) exists when the sketch included <SPI.h> first.
#if defined(ARDUINO) && !defined(HWBRIDGE_HOST_BUILD) && \
    (defined(_SPI_H_INCLUDED) || defined(SPI_MODE0))
#include <Arduino.h>

namespace hwbridge {
namespace can {

/**
 * The MCP2515 on the Arduino SPI bus, chip select on a pin of its own (setPin(), default 10).
 * Each transaction sets mode 0, MSB first and the clock (F_CPU / 2, at most 8 MHz; the chip takes
 * 10), so other SPI devices may share the bus outside interrupts. (Register writes rather than
 * SPI.beginTransaction(): the same image from hwbridge firmware build and the Arduino IDE.)
 */
class ArduinoSpiPort {
 public:
  constexpr ArduinoSpiPort() : cs_(0) {}  // 0: pin 10 (pin 0 is the serial port's RX)
  void setPin(uint8_t cs) { cs_ = cs; }
  void begin() {
    if (cs_ == 0) cs_ = 10;
    pinMode(cs_, OUTPUT);
    digitalWrite(cs_, HIGH);
    SPI.begin();
  }
  void select() {
    SPI.setBitOrder(MSBFIRST);
    SPI.setDataMode(SPI_MODE0);
#if F_CPU > 16000000UL
    SPI.setClockDivider(SPI_CLOCK_DIV4);
#else
    SPI.setClockDivider(SPI_CLOCK_DIV2);
#endif
    digitalWrite(cs_, LOW);
  }
  void deselect() { digitalWrite(cs_, HIGH); }
  uint8_t transfer(uint8_t b) { return SPI.transfer(b); }
  uint32_t micros() { return ::micros(); }
  uint32_t seed() {
    uint32_t s = ::micros();
    for (uint8_t i = 0; i < 8; ++i) s = (s << 3) ^ static_cast<uint32_t>(analogRead(A0)) ^ ::micros();
    return s;
  }

 private:
  uint8_t cs_;
};

typedef Mcp2515T<ArduinoSpiPort> Mcp2515;

}  // namespace can
}  // namespace hwbridge
#endif

#endif  // HWBRIDGE_CAN_MCP2515_H
