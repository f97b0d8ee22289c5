// The MCP2515 driver against a register-level fake of the chip: the fake decodes the SPI
// transactions (RESET, READ, WRITE, BIT MODIFY, READ STATUS, LOAD TX BUFFER, RTS, READ RX
// BUFFER) on a register file as the data sheet describes them, "transmits" a requested buffer by
// decoding its registers into a frame, and "receives" by writing a frame into RXB0/RXB1 as the
// acceptance filters and masks allow (filters and masks written in configuration mode only).
// Checked: the bit timing of 8/16 MHz crystals at 125k..1M, reset and the modes, frames both
// ways (extended and standard ids, every length), receive buffer order, the acceptance filters
// a node sets (its transfers and claims through, other nodes' traffic kept off SPI), the priority buffers,
// a frame nobody acknowledges aborted after the timeout, overflow and remote frames counted,
// and CanHardware running over it.
#include <hwbridge/can/can_hardware.h>
#include <hwbridge/can/mcp2515.h>

#include <deque>

#include "can_check.h"

using namespace hwbridge::can;

namespace {

struct Chip {
  uint8_t reg[128];
  std::vector<uint8_t> cmd;  // bytes of the current transaction
  bool selected;
  bool acked;          // another node acknowledges: a requested frame goes at once
  uint32_t clock;
  std::vector<std::pair<Frame, uint8_t> > sent;  // frame, buffer
  unsigned transactions;
  uint8_t pending_clear;

  Chip() : selected(false), acked(true), clock(0), transactions(0), pending_clear(0) {
    memset(reg, 0xAA, sizeof(reg));
  }
  void reset() {
    memset(reg, 0, sizeof(reg));
    reg[0x0F] = 0x87;  // CANCTRL: configuration mode, CLKOUT
    reg[0x0E] = 0x80;  // CANSTAT: configuration mode
  }
  void write(uint8_t addr, uint8_t v) {
    addr &= 0x7F;
    const bool filter_or_mask = addr < 0x28 && (addr & 0x0F) < 0x0C && addr != 0x0C && addr != 0x0D;
    CHECK(!filter_or_mask || configMode(), "filter/mask register %02x written outside configuration mode", addr);
    if (addr == 0x0E) return;  // CANSTAT is read-only
    if ((addr & 0x0F) == 0x0E) return;
    reg[addr] = v;
    if (addr == 0x0F) reg[0x0E] = static_cast<uint8_t>((reg[0x0E] & 0x1F) | (v & 0xE0));
    if ((addr == 0x30 || addr == 0x40 || addr == 0x50) && (v & 0x08)) transmit(addr);
  }
  bool configMode() const { return (reg[0x0E] & 0xE0) == 0x80; }
  // The 29 id bits of the four registers SIDH, SIDL, EID8, EID0 at a (a buffer, filter or mask).
  uint32_t id_at(uint8_t a) const {
    return static_cast<uint32_t>(reg[a]) << 21 | static_cast<uint32_t>(reg[a + 1] >> 5) << 18 |
           static_cast<uint32_t>(reg[a + 1] & 3) << 16 | static_cast<uint32_t>(reg[a + 2]) << 8 |
           reg[a + 3];
  }
  void transmit(uint8_t ctrl) {
    if (configMode() || !acked) return;  // TXREQ stays set
    const uint8_t* r = &reg[ctrl + 1];
    Frame f;
    f.extended = (r[1] & 0x08) != 0;
    const uint32_t id = id_at(static_cast<uint8_t>(ctrl + 1));
    f.id = f.extended ? id : id >> 18;  // a standard id: SIDH and SIDL's top 3 bits
    f.len = r[4] & 0x0F;
    memcpy(f.data, r + 5, 8);
    sent.push_back(std::make_pair(f, static_cast<uint8_t>((ctrl - 0x30) >> 4)));
    reg[ctrl] = static_cast<uint8_t>(reg[ctrl] & ~0x08);
    reg[0x2C] |= static_cast<uint8_t>(0x04 << ((ctrl - 0x30) >> 4));
  }
  // Filter (at f) and mask (at m) registers against a frame: the masked id bits must be equal,
  // and the filter's EXIDE must match the frame's kind (standard frames: the 11 bits only).
  bool matches(uint8_t f, uint8_t m, uint32_t id, bool ext) const {
    if (((reg[f + 1] & 0x08) != 0) != ext) return false;
    const uint32_t fid = id_at(f);
    const uint32_t mid = id_at(m);
    const uint32_t frame = ext ? id : id << 18;
    const uint32_t used = ext ? mid : (mid & 0x1FFC0000UL);
    return ((fid ^ frame) & used) == 0;
  }
  // A receive buffer's acceptance: RXM bits 11 take any frame, 00 the filters'.
  bool accepts(uint8_t ctrl, uint32_t id, bool ext) const {
    if ((reg[ctrl] & 0x60) == 0x60) return true;
    static const uint8_t rxb0[2] = {0x00, 0x04};
    static const uint8_t rxb1[4] = {0x08, 0x10, 0x14, 0x18};
    const uint8_t* f = ctrl == 0x60 ? rxb0 : rxb1;
    const uint8_t n = ctrl == 0x60 ? 2 : 4;
    for (uint8_t i = 0; i < n; ++i) {
      if (matches(f[i], ctrl == 0x60 ? 0x20 : 0x24, id, ext)) return true;
    }
    return false;
  }
  // The bus delivers a frame: RXB0 when its filters take it and it is free (else RXB1 when
  // rollover is on), RXB1 when only its filters take it; 1 or 2 (the buffer), 0 (no filter took
  // it: gone, not an error), -1 (overflow).
  int deliver(uint32_t id, bool ext, const uint8_t* data, uint8_t len, bool remote = false) {
    uint8_t base;
    const bool to0 = accepts(0x60, id, ext);
    if (to0 && !(reg[0x2C] & 1)) {
      base = 0x60;
    } else if ((to0 && (reg[0x60] & 0x04)) || (!to0 && accepts(0x70, id, ext))) {
      if (reg[0x2C] & 2) {
        reg[0x2D] |= to0 && !(reg[0x60] & 0x04) ? 0x40 : 0x80;
        reg[0x2C] |= 0x20;
        return -1;
      }
      base = 0x70;
    } else if (to0) {
      reg[0x2D] |= 0x40;
      reg[0x2C] |= 0x20;
      return -1;
    } else {
      return 0;
    }
    uint8_t* r = &reg[base + 1];
    if (ext) {
      r[0] = static_cast<uint8_t>(id >> 21);
      r[1] = static_cast<uint8_t>(((id >> 13) & 0xE0) | 0x08 | ((id >> 16) & 3));
      r[2] = static_cast<uint8_t>(id >> 8);
      r[3] = static_cast<uint8_t>(id);
      r[4] = static_cast<uint8_t>(len | (remote ? 0x40 : 0));
    } else {
      r[0] = static_cast<uint8_t>(id >> 3);
      r[1] = static_cast<uint8_t>((id & 7) << 5 | (remote ? 0x10 : 0));
      r[2] = r[3] = 0;
      r[4] = len;
    }
    memcpy(r + 5, data, len);
    reg[0x2C] |= base == 0x60 ? 1 : 2;
    return base == 0x60 ? 1 : 2;
  }

  // --- Port
  void begin() {}
  void select() {
    CHECK(!selected, "select twice");
    selected = true;
    cmd.clear();
  }
  void deselect() {
    CHECK(selected, "deselect without select");
    selected = false;
    ++transactions;
    if (!cmd.empty()) {
      const uint8_t op = cmd[0];
      if (op == 0xC0) reset();
      if ((op & 0xF0) == 0x80) {  // RTS
        for (uint8_t b = 0; b < 3; ++b) {
          if (op & (1 << b)) write(static_cast<uint8_t>(0x30 + 0x10 * b), reg[0x30 + 0x10 * b] | 0x08);
        }
      }
      if ((op & 0xF9) == 0x90 && cmd.size() > 1) reg[0x2C] &= static_cast<uint8_t>(~pending_clear);
    }
  }
  uint8_t transfer(uint8_t b) {
    CHECK(selected, "SPI byte with CS high");
    cmd.push_back(b);
    const size_t n = cmd.size();
    const uint8_t op = cmd[0];
    if (n == 1) {
      if ((op & 0xF9) == 0x90) pending_clear = (op & 4) ? 2 : 1;
      return 0xFF;
    }
    if (op == 0x03) {  // READ addr, then data with auto-increment
      if (n == 2) return 0xFF;
      return reg[(cmd[1] + n - 3) & 0x7F];
    }
    if (op == 0x02) {  // WRITE addr, data...
      if (n >= 3) write(static_cast<uint8_t>(cmd[1] + n - 3), b);
      return 0xFF;
    }
    if (op == 0x05) {  // BIT MODIFY addr mask data
      if (n == 4) {
        const uint8_t a = cmd[1];
        const uint8_t v = static_cast<uint8_t>((reg[a] & ~cmd[2]) | (cmd[3] & cmd[2]));
        if (a == 0x0F || a == 0x2C || a == 0x2D || a == 0x30 || a == 0x40 || a == 0x50) {
          if (a == 0x0F) {
            write(a, v);
          } else {
            reg[a] = v;
          }
        } else {
          CHECK(false, "bit modify of register %02x", a);
        }
      }
      return 0xFF;
    }
    if (op == 0xA0) {  // READ STATUS
      const uint8_t f = reg[0x2C];
      return static_cast<uint8_t>((f & 3) | ((reg[0x30] & 8) ? 0x04 : 0) | ((f & 4) ? 0x08 : 0) |
                                  ((reg[0x40] & 8) ? 0x10 : 0) | ((f & 8) ? 0x20 : 0) |
                                  ((reg[0x50] & 8) ? 0x40 : 0) | ((f & 0x10) ? 0x80 : 0));
    }
    if ((op & 0xF8) == 0x40) {  // LOAD TX BUFFER from SIDH (0, 2, 4) or D0 (1, 3, 5)
      const uint8_t base = static_cast<uint8_t>(0x31 + 0x10 * ((op & 7) >> 1) + ((op & 1) ? 5 : 0));
      CHECK(!(reg[base & 0xF0] & 0x08), "load of a buffer waiting to send");
      reg[base + n - 2] = b;
      return 0xFF;
    }
    if ((op & 0xF9) == 0x90) {  // READ RX BUFFER
      const uint8_t base = static_cast<uint8_t>(((op & 4) ? 0x71 : 0x61) + ((op & 2) ? 5 : 0));
      return reg[base + n - 2];
    }
    CHECK(false, "unknown instruction %02x", op);
    return 0;
  }
  uint32_t micros() { return clock += 50; }
  uint32_t seed() { return 7; }
};

typedef Mcp2515T<Chip> Driver;

void timing() {
  const uint32_t crystals[2] = {8000000UL, 16000000UL};
  const uint32_t rates[4] = {125000UL, 250000UL, 500000UL, 1000000UL};
  for (int c = 0; c < 2; ++c) {
    for (int r = 0; r < 4; ++r) {
      BitTiming t;
      CHECK(mcp2515_timing(crystals[c], rates[r], &t), "%lu at %lu", (unsigned long)crystals[c],
            (unsigned long)rates[r]);
      const uint32_t brp = t.cnf1 & 0x3F;
      const uint32_t prop = (t.cnf2 & 7) + 1u;
      const uint32_t ps1 = ((t.cnf2 >> 3) & 7) + 1u;
      const uint32_t ps2 = (t.cnf3 & 7) + 1u;
      const uint32_t ntq = 1 + prop + ps1 + ps2;
      CHECK(t.cnf2 & 0x80, "BTLMODE");
      CHECK(crystals[c] / (2 * (brp + 1) * ntq) == rates[r] &&
                crystals[c] % (2 * (brp + 1) * ntq) == 0,
            "rate");
      CHECK(prop + ps1 >= ps2, "PS1 + PropSeg >= PS2");
      if (ntq > 4) {
        CHECK(ps2 >= 2 && (1 + prop + ps1) * 100 / ntq >= 60 && (1 + prop + ps1) * 100 / ntq <= 85,
              "sample point %lu%% (%lu tq)", (unsigned long)((1 + prop + ps1) * 100 / ntq),
              (unsigned long)ntq);
      }
    }
  }
  BitTiming t;
  CHECK(mcp2515_timing(16000000UL, 500000UL, &t) && t.cnf1 == 0 && t.cnf3 == 3, "16 MHz 500k");
  CHECK(!mcp2515_timing(16000000UL, 0, &t) && !mcp2515_timing(8000000UL, 3000000UL, &t), "bad");
}

void frames() {
  Driver d;
  d.configure(250000UL, 8000000UL);
  CHECK(d.begin(), "begin");
  Chip& chip = d.port();
  CHECK((chip.reg[0x0E] & 0xE0) == 0, "normal mode");
  BitTiming t;
  mcp2515_timing(8000000UL, 250000UL, &t);
  CHECK(chip.reg[0x2A] == t.cnf1 && chip.reg[0x29] == t.cnf2 && chip.reg[0x28] == t.cnf3, "CNF");
  CHECK((chip.reg[0x60] & 0x64) == 0x64, "RXB0: any frame, rollover");
  Frame f;
  CHECK(!d.receive(&f), "nothing received");

  // Sending: every length, extended and standard ids, priorities to their buffers.
  Rng rng(3);
  for (uint8_t len = 0; len <= 8; ++len) {
    Frame s;
    s.extended = len != 3;
    s.id = s.extended ? (rng.next() & 0x1FFFFFFFUL) : (rng.next() & 0x7FF);
    s.len = len;
    for (uint8_t i = 0; i < 8; ++i) s.data[i] = static_cast<uint8_t>(rng.next());
    const uint8_t priority = static_cast<uint8_t>(len % 8);
    CHECK(d.send(s, priority), "send %u", len);
    const Frame& g = chip.sent.back().first;
    CHECK(g.id == s.id && g.extended == s.extended && g.len == len &&
              memcmp(g.data, s.data, len) == 0,
          "sent frame %u: %08lx", len, (unsigned long)g.id);
    CHECK(chip.sent.back().second == (priority <= 3 ? 1 : 0), "buffer of priority %u", priority);
  }
  CHECK((chip.reg[0x40] & 3) > (chip.reg[0x30] & 3), "TXB1 before TXB0");

  // Receiving: RXB0 then RXB1 (rollover), ids and data intact; a third overflows.
  const uint8_t a[8] = {1, 2, 3, 4, 5, 6, 7, 0xE0};
  CHECK(chip.deliver(0x14010005UL, true, a, 8) == 1, "rxb0");
  CHECK(chip.deliver(0x123, false, a, 3) == 2, "rxb1");
  CHECK(chip.deliver(0x1, true, a, 1) == -1, "overflow");
  CHECK(d.receive(&f) && f.id == 0x14010005UL && f.extended && f.len == 8 &&
            memcmp(f.data, a, 8) == 0,
        "first frame");
  CHECK(d.receive(&f) && f.id == 0x123 && !f.extended && f.len == 3, "second frame");
  CHECK(!d.receive(&f), "no third");
  CHECK(d.stats.rx_overflow == 1 && d.stats.errors == 1, "overflow counted");
  CHECK((chip.reg[0x2C] & 0x23) == 0, "flags cleared");
  // Remote frames are not ours.
  chip.deliver(0x14010005UL, true, a, 0, true);
  chip.deliver(0x14010006UL, true, a, 2);
  CHECK(d.receive(&f) && f.id == 0x14010006UL && d.stats.remote == 1, "remote skipped");

  // Nobody acknowledges: the frame is aborted after the timeout, and the next one waits its turn.
  chip.acked = false;
  Frame s;
  s.extended = true;
  s.id = 0x14000005UL;
  s.len = 1;
  s.data[0] = 0xE0;
  CHECK(d.send(s, 5), "queued");  // TXB0 was free
  CHECK(!d.send(s, 5), "times out");
  CHECK(d.stats.tx_timeouts == 1 && !(chip.reg[0x30] & 0x08), "aborted");
  chip.acked = true;
  CHECK(d.send(s, 5), "sends again");
}

/** A node's acceptance filters (CAN.md 11): format-2 transfers to it and format-1 frames from
 * the host in RXB0 (rolling over into RXB1); the host's format-2 claims and format-1 claims in
 * RXB1; everything else (other nodes' format-2 traffic, standard ids) never on SPI. */
void filters() {
  Driver d;
  d.configure(500000UL, 16000000UL);
  CHECK(d.begin(5), "begin");
  Chip& chip = d.port();
  CHECK(chip.reg[0x60] == 0x04 && chip.reg[0x70] == 0x00, "filters on, rollover: %02x %02x",
        chip.reg[0x60], chip.reg[0x70]);
  const uint8_t a[8] = {1, 2, 3, 4, 5, 6, 7, 0xE0};
  const uint32_t to_me = encode_id2(4, kReliable, 3, 5, 0, 0xE1, 3);
  const uint32_t to_me_1 = encode_id(4, kReliable, 3, 5, 0);
  const uint32_t host_claim = encode_id2(3, kNode, 1, 0, 0, 0, 0);
  const uint32_t host_claim_1 = encode_id(3, kNode, 1, 0, 0);
  const uint32_t twin_1 = encode_id(3, kNode, 1, 0, 5);  // a format-1 board with node id 5
  // other nodes' traffic and standard ids: filtered out by the chip (not overflow, not received)
  CHECK(chip.deliver(encode_id2(4, kReliable, 3, 6, 0, 0xE1, 0), true, a, 8) == 0, "to node 6");
  CHECK(chip.deliver(encode_id2(5, kBestEffort, 1, 0, 7, 0x20, 0), true, a, 8) == 0,
        "node 7 to the host");
  CHECK(chip.deliver(encode_id2(3, kNode, 1, 0, 7, 0, 0), true, a, 7) == 0, "node 7's claim");
  CHECK(chip.deliver(encode_id2(3, kNode, 1, 0, 7, 0, 0) | kClaimChains, true, a, 7) == 0,
        "node 7's claim, taking chains");
  CHECK(chip.deliver(encode_id(4, kReliable, 3, 6, 7), true, a, 8) == 0, "format 1, 7 to 6");
  CHECK(chip.deliver(encode_id(2, kBestEffort, 0, 0x45, 5), true, a, 8) == 0, "another destination");
  CHECK(chip.deliver(5 << 7, false, a, 3) == 0, "a standard id");
  CHECK(chip.deliver(kFormat2Bit | 5, false, a, 3) == 0, "a standard id, format-2 bits");
  Frame f;
  CHECK(!d.receive(&f) && d.stats.rx_frames == 0 && d.stats.rx_overflow == 0, "nothing came");
  // every field but the format, direction and node may vary in format 2
  CHECK(chip.deliver(to_me, true, a, 8) == 1, "to me: RXB0");
  CHECK(chip.deliver(host_claim, true, a, 7) == 2, "the host's claim: RXB1");
  CHECK(d.receive(&f) && f.id == to_me, "first");
  CHECK(d.receive(&f) && f.id == host_claim && f.len == 7, "the claim");
  CHECK(chip.deliver(twin_1, true, a, 7) == 2 && d.receive(&f) && f.id == twin_1, "a twin");
  CHECK(chip.deliver(to_me_1, true, a, 8) == 1 && d.receive(&f) && f.id == to_me_1, "format 1");
  CHECK(chip.deliver(host_claim_1, true, a, 7) == 1 && d.receive(&f) && f.id == host_claim_1,
        "a format-1 host's claim");
  // a host that takes chained transfers sets bit 11 of its claims (CAN.md 12): RXB1 too
  CHECK(chip.deliver(host_claim | kClaimChains, true, a, 7) == 2 && d.receive(&f) &&
            f.id == (host_claim | kClaimChains),
        "the claim of a host taking chains");
  const uint32_t ack = encode_id2(1, kAck, 0, 5, 0, 0x11, 0);
  CHECK(chip.deliver(ack, true, a, 2) == 1 && chip.deliver(to_me, true, a, 1) == 2, "rollover");
  CHECK(chip.deliver(host_claim, true, a, 7) == -1 && chip.deliver(to_me, true, a, 1) == -1,
        "both full");
  CHECK(d.receive(&f) && f.id == ack && d.receive(&f) && f.id == to_me && !d.receive(&f),
        "both read");
  CHECK(d.stats.rx_overflow == 1 && d.stats.rx_frames == 8, "overflow %lu, frames %lu",
        (unsigned long)d.stats.rx_overflow, (unsigned long)d.stats.rx_frames);
  // begin() without a node: every frame, as before
  Driver any;
  any.configure(500000UL, 16000000UL);
  CHECK(any.begin(), "begin");
  CHECK(any.port().deliver(encode_id(4, kReliable, 3, 6, 0), true, a, 8) == 1, "no filters");
}

void over_can_hardware() {
  CanHardware<Driver, 72, 2, 160> hw;
  hw.setNode(9);
  hw.driver().configure(1000000UL, 16000000UL);
  CHECK(hw.init(0), "init");
  CHECK(hw.read() == -1, "nothing");
  Chip& chip = hw.driver().port();
  CHECK(chip.sent.size() == 1 &&
            chip.sent[0].first.id == encode_id2(3, kNode, 1, 0, 9, 0, 0) &&
            chip.sent[0].second == 1,
        "claim through TXB1");
  // A two-frame transfer from the host arrives as one COBS run.
  const uint8_t dg[9] = {0x50, 0x03, 0xc8, 0x2a, 0, 0, 0, 0xc9, 0xbb};
  struct Q {
    Chip* chip;
    bool operator()(const Frame& f) { return chip->deliver(f.id, true, f.data, f.len) > 0; }
  } q = {&chip};
  // (format 1: the host has not claimed yet, and every board understands both formats)
  send_transfer<kClassicMtu>(encode_id(4, kReliable, 3, 9, 0), dg, 9, 0, kClassicMtu, q);
  std::vector<uint8_t> got;
  for (int c = hw.read(); c >= 0; c = hw.read()) got.push_back(static_cast<uint8_t>(c));
  uint8_t want[16];
  const size_t n = hwbridge::cobs_encode(dg, 9, want, sizeof want);
  CHECK(got.size() == n + 1 && memcmp(got.data(), want, n) == 0 && got[n] == 0, "read %s",
        to_hex(got).c_str());
  // And the same datagram written by the session leaves in format 2 as one frame in TXB0:
  // its 4 payload bytes and the tail byte (seq 0xc8: bits 7..5 in the id, 4..0 in the tail).
  for (size_t i = 0; i < n; ++i) hw.put(want[i]);
  hw.put(0);
  CHECK(chip.sent.size() == 2 && chip.sent[1].second == 0 &&
            chip.sent[1].first.id == encode_id2(4, kReliable, 3, 0, 9, 0xc8, 0) &&
            to_hex(chip.sent[1].first.data, chip.sent[1].first.len) == "2a000000e8",
        "sent %zu", chip.sent.size());
  // A format-1 host claims: the board speaks format 1, the same datagram as two frames.
  const uint8_t host_uid[6] = {9, 9, 9, 9, 9, 9};
  send_transfer<kClassicMtu>(encode_id(3, kNode, 1, 0, 0), host_uid, 6, 0, kClassicMtu, q);
  CHECK(hw.read() == -1 && hw.format() == kFormat1, "format 1 after the host's claim");
  for (size_t i = 0; i < n; ++i) hw.put(want[i]);
  hw.put(0);
  CHECK(chip.sent.size() == 4 && chip.sent[2].first.id == encode_id(4, kReliable, 3, 0, 9) &&
            to_hex(chip.sent[3].first.data, chip.sent[3].first.len) == "c9bb30ee40",
        "sent %zu", chip.sent.size());
  // The node's filters: a format-2 transfer to node 8 never arrives (a format-1 one from the
  // host does, and the transport skips it); a format-1 claim of node 9 by another unique id
  // comes through them to the conflict count.
  send_transfer<kClassicMtu>(encode_id2(4, kReliable, 3, 8, 0, 0xc8, 0), dg + 3, 4, 8,
                             kClassicMtu, q);
  CHECK(hw.read() == -1 && hw.driver().stats.rx_frames == 3, "another node's transfer");
  send_transfer<kClassicMtu>(encode_id(4, kReliable, 3, 8, 0), dg, 9, 1, kClassicMtu, q);
  CHECK(hw.read() == -1 && hw.driver().stats.rx_frames == 5 && hw.rxStats().foreign == 2,
        "another node's format-1 transfer: skipped");
  const uint8_t other[6] = {1, 2, 3, 4, 5, 6};
  send_transfer<kClassicMtu>(encode_id(3, kNode, 1, 0, 9), other, 6, 0, kClassicMtu, q);
  CHECK(hw.read() == -1 && hw.ownConflicts() == 1, "claim of node 9: %lu conflicts",
        (unsigned long)hw.ownConflicts());
}

}  // namespace

int main() {
  timing();
  frames();
  filters();
  over_can_hardware();
  printf("test_mcp2515: %lu checks passed\n", g_checks);
  return 0;
}
