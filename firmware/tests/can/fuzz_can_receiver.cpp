// Seeded, time-bounded fuzz of the C++ CAN receiver: valid transfers from several senders,
// interleaved, with frames dropped, repeated, reordered, corrupted, and random frames mixed in.
// Checked: no crash or out-of-bounds access (run under ASan/UBSan), every delivered transfer is
// one that was sent on its id and no larger than the receiver allows, the counters add up,
// and a clean stream (no damage) delivers every transfer exactly once. CanHardware gets random
// session bytes and bus frames too (hardware_round), and chained transfers to send among other
// datagrams, some broken off, the bus refusing now and then (chain_round).
//   fuzz_can_receiver SEED SECONDS
#include <hwbridge/can/can_hardware.h>
#include <hwbridge/can/transport.h>
#include <time.h>

#include <algorithm>
#include <map>
#include <set>

#include "can_check.h"

using namespace hwbridge::can;

namespace {

const size_t kMax = 80;
typedef TransferReceiver<kMax, 3> Receiver;

struct Sent {
  uint32_t id;
  Bytes payload;
};

struct Out {
  std::vector<Frame>* frames;
  bool operator()(const Frame& f) {
    frames->push_back(f);
    return true;
  }
};

void round(Rng& rng, bool clean, unsigned long* delivered_total) {
  Receiver rx(5);
  TidTable<8> tids;
  std::map<uint32_t, std::set<Bytes> > sent;
  std::vector<Frame> frames;
  uint32_t now = rng.next();
  const unsigned transfers = 1 + rng.below(12);
  std::vector<std::vector<Frame> > per;
  for (unsigned i = 0; i < transfers; ++i) {
    const uint8_t channel = static_cast<uint8_t>(rng.below(3));
    const uint8_t kind = static_cast<uint8_t>(rng.below(3));
    const uint8_t dest = rng.below(8) == 0 ? 6 : 5;
    const uint8_t seq = static_cast<uint8_t>(rng.next());
    const bool format2 = rng.below(2) == 0;  // format 2: from the host, the tid is seq's bits
    const uint32_t id =
        format2 ? encode_id2(static_cast<uint8_t>(rng.below(8)), kind, channel, dest, 0, seq,
                             static_cast<uint8_t>(rng.below(4)))
                : encode_id(static_cast<uint8_t>(rng.below(8)), kind, channel, dest,
                            static_cast<uint8_t>(rng.below(2)));
    Bytes p(rng.below(clean ? kMax + 1 : kMax + 20));
    for (size_t k = 0; k < p.size(); ++k) p[k] = static_cast<uint8_t>(rng.below(4) ? rng.next() : 0);
    std::vector<Frame> fs;
    Out o = {&fs};
    send_transfer<kClassicMtu>(id, p.data(), p.size(), format2 ? seq : tids.next(id), kClassicMtu,
                               o);
    if (dest == 5 && p.size() <= kMax) sent[id].insert(p);
    per.push_back(fs);
  }
  // Interleave the transfers (clean: at most 3 at once on distinct ids, frames in order).
  std::vector<size_t> pos(per.size(), 0);
  size_t remaining = per.size();
  size_t first = 0;
  while (remaining) {
    const size_t window = clean ? 1 : 4;
    const size_t pick = first + rng.below(static_cast<uint32_t>(
                                    std::min(window, per.size() - first)));
    if (pos[pick] < per[pick].size()) {
      frames.push_back(per[pick][pos[pick]++]);
      if (pos[pick] == per[pick].size()) --remaining;
    }
    while (first < per.size() && pos[first] == per[first].size()) ++first;
  }
  // Corrupted or forged frames may form a single-frame transfer nobody sent (CAN's own CRC,
  // and the datagram's, catch those on a real bus); drops, repeats and reordering may not.
  bool forged = false;
  if (!clean) {
    const unsigned damage = rng.below(6);
    for (unsigned k = 0; k < damage && !frames.empty(); ++k) {
      const size_t at = rng.below(static_cast<uint32_t>(frames.size()));
      switch (rng.below(6)) {
        case 0: frames.erase(frames.begin() + static_cast<long>(at)); break;
        case 1: frames.insert(frames.begin() + static_cast<long>(at), frames[at]); break;
        case 2: std::swap(frames[at], frames[rng.below(static_cast<uint32_t>(frames.size()))]); break;
        case 3: forged = true; frames[at].data[rng.below(frames[at].len ? frames[at].len : 1)] ^=
                    static_cast<uint8_t>(1 + rng.below(255));
          break;
        case 4: forged = true; frames[at].len = static_cast<uint8_t>(rng.below(9)); break;
        default: {
          forged = true;
          Frame g;
          g.id = rng.next() & (rng.below(2) ? 0x1FFFFFFFUL : 0xFFFFFFFFUL);
          g.extended = rng.below(8) != 0;
          g.len = static_cast<uint8_t>(rng.below(9));
          for (uint8_t b = 0; b < 8; ++b) g.data[b] = static_cast<uint8_t>(rng.next());
          frames.insert(frames.begin() + static_cast<long>(at), g);
        }
      }
    }
  }
  unsigned delivered = 0;
  for (size_t i = 0; i < frames.size(); ++i) {
    now += rng.below(clean ? 1000 : 400000);
    Transfer t;
    if (rx.feed(frames[i].id, frames[i].extended, frames[i].data, frames[i].len, now, &t)) {
      CHECK(t.size <= kMax, "size %zu", t.size);
      if (t.id.kind != kNode) {
        const Bytes p(t.payload, t.payload + t.size);
        const uint32_t id = frames[i].id;
        CHECK(forged || (sent.count(id) && sent[id].count(p)), "a transfer nobody sent on %08lx: %s",
              static_cast<unsigned long>(id), to_hex(p).c_str());
        ++delivered;
      }
    }
    if (rng.below(16) == 0) rx.expire(now);
  }
  CHECK(rx.stats.frames == frames.size(), "frames counted");
  if (clean) {
    size_t want = 0;
    for (std::map<uint32_t, std::set<Bytes> >::iterator it = sent.begin(); it != sent.end(); ++it) {
      want += it->second.size();
    }
    // Identical payloads sent twice on one id within 1 s with different tids are distinct
    // transfers and both delivered; the sets hold them once, so count at least.
    CHECK(delivered >= want, "clean stream: %u of %zu delivered", delivered, want);
    CHECK(rx.stats.dropped() == 0, "clean stream: %u dropped", rx.stats.dropped());
  }
  *delivered_total += delivered;
}

// CanHardware with random session bytes (valid COBS runs, garbage, runs too long) and random
// bus frames (the host's transfers, damaged ones, others'): nothing out of bounds, every
// transfer sent carries at most MaxDatagram bytes, every datagram read is a whole COBS run.
struct FuzzDriver {
  Rng* rng;
  std::vector<Frame> inbox;
  size_t next;
  std::vector<Frame> sent;
  uint32_t now;
  bool begin(uint8_t) { return true; }
  bool receive(Frame* f) {
    if (next >= inbox.size()) return false;
    *f = inbox[next++];
    return true;
  }
  bool send(const Frame& f, uint8_t) {
    CHECK(f.len >= 1 && f.len <= 8 && f.extended, "frame sent");
    if (rng->below(50) == 0) return false;  // the bus refuses now and then
    sent.push_back(f);
    return true;
  }
  uint32_t micros() { return now += rng->below(20000); }
  uint32_t seed() { return rng->next(); }
};

unsigned long g_read_datagrams = 0;
unsigned long g_sent_transfers = 0;

void hardware_round(Rng& rng) {
  typedef CanHardware<FuzzDriver, 40, 2, 90> Hw;
  static Hw hw;
  hw = Hw();
  FuzzDriver& d = hw.driver();
  d.rng = &rng;
  d.next = 0;
  d.now = rng.next();
  hw.setNode(static_cast<uint8_t>(1 + rng.below(127)));
  CHECK(hw.init(0), "init");
  const uint8_t node = hw.node();
  TidTable<4> tids;
  for (unsigned k = 0; k < 20; ++k) {
    Bytes p(rng.below(50));
    for (size_t i = 0; i < p.size(); ++i) p[i] = static_cast<uint8_t>(rng.below(3) ? rng.next() : 0);
    const uint8_t src = rng.below(4) ? 0 : static_cast<uint8_t>(rng.below(128));
    const uint8_t dst = rng.below(4) ? node : static_cast<uint8_t>(rng.below(128));
    const uint8_t priority = static_cast<uint8_t>(rng.below(8));
    const uint8_t kind = static_cast<uint8_t>(rng.below(4));
    const uint8_t channel = static_cast<uint8_t>(rng.below(4));
    const uint8_t seq = static_cast<uint8_t>(rng.next());
    // format 2 (one end the host) or format 1, as they come
    const bool format2 = (src == 0 || dst == 0) && rng.below(2) == 0;
    const uint32_t id = format2 ? encode_id2(priority, kind, channel, dst, src, seq,
                                             static_cast<uint8_t>(rng.below(4)))
                                : encode_id(priority, kind, channel, dst, src);
    std::vector<Frame> fs;
    Out o = {&fs};
    send_transfer<kClassicMtu>(id, p.data(), p.size(), format2 ? seq : tids.next(id), kClassicMtu,
                               o);
    for (size_t i = 0; i < fs.size(); ++i) {
      if (rng.below(30) == 0) fs[i].data[rng.below(8)] ^= 0x10;
      if (rng.below(40) != 0) d.inbox.push_back(fs[i]);
    }
  }
  Bytes readback;
  for (unsigned step = 0; step < 400; ++step) {
    if (rng.below(3) == 0) {
      const int c = hw.read();
      if (c >= 0) readback.push_back(static_cast<uint8_t>(c));
    } else {
      const unsigned what = rng.below(10);
      hw.put(what == 0 ? 0 : static_cast<uint8_t>(what < 3 ? rng.next() : 1 + rng.below(255)));
    }
  }
  for (int c = hw.read(); c >= 0; c = hw.read()) readback.push_back(static_cast<uint8_t>(c));
  // Whole COBS runs only, each a datagram of at most 40 bytes.
  size_t start = 0;
  for (size_t i = 0; i < readback.size(); ++i) {
    if (readback[i] != 0) continue;
    uint8_t out[64];
    size_t n = 0;
    CHECK(i > start && i - start <= sizeof(out) &&
              hwbridge::cobs_decode(&readback[start], i - start, out, &n) && n <= 40,
          "a bad run in the read bytes");
    ++g_read_datagrams;
    start = i + 1;
  }
  // The transfers sent reassemble to at most 40 bytes each.
  TransferReceiver<64, 8> rx(0);
  for (size_t i = 0; i < d.sent.size(); ++i) {
    Transfer t;
    if (rx.feed(d.sent[i].id, true, d.sent[i].data, d.sent[i].len, 0, &t)) {
      CHECK(t.size <= 40, "a transfer of %zu bytes sent", t.size);
      ++g_sent_transfers;
    }
  }
}

// Chains (CAN.md 12): a board under a host that takes chains writes whole and broken-off
// fragmented best-effort messages among other datagrams, the driver refusing now and then; every
// chain that went out whole is the message's bytes with a right CRC (checked by a format-2
// receiver given the chain's frames under a plain id), and nothing else is ever sent as a chain.
unsigned long g_chains = 0;

Bytes native(uint8_t flags, uint8_t channel, uint8_t seq, const Bytes& payload) {
  Bytes d;
  d.push_back(flags);
  d.push_back(channel);
  d.push_back(seq);
  d.insert(d.end(), payload.begin(), payload.end());
  const uint16_t crc = hwbridge::crc16(d.data(), d.size());
  d.push_back(static_cast<uint8_t>(crc & 0xFF));
  d.push_back(static_cast<uint8_t>(crc >> 8));
  return d;
}

void chain_round(Rng& rng) {
  typedef CanHardware<FuzzDriver, 72, 2, 160> Hw;
  static Hw hw;
  hw = Hw();
  FuzzDriver& d = hw.driver();
  d.rng = &rng;
  d.next = 0;
  d.now = rng.next();
  hw.setNode(static_cast<uint8_t>(1 + rng.below(127)));
  std::vector<Frame> claim;
  Out o = {&claim};
  const uint8_t uid[6] = {1, 2, 3, 4, 5, 6};
  send_transfer<kClassicMtu>(encode_id2(3, kNode, 1, 0, 0, 0, 0) | kClaimChains, uid, 6, 0,
                             kClassicMtu, o);
  d.inbox = claim;
  CHECK(hw.init(0) && hw.read() == -1 && hw.hostTakesChains(), "the host takes chains");
  std::vector<Bytes> messages;  // each chain's message bytes, in the order begun
  uint8_t seq = static_cast<uint8_t>(rng.next());
  for (unsigned k = 0; k < 6; ++k) {
    const size_t size = rng.below(2) ? 32 : 64;
    Bytes msg(size - 3 + rng.below(400));
    for (size_t i = 0; i < msg.size(); ++i) msg[i] = static_cast<uint8_t>(rng.next());
    const uint8_t channel = static_cast<uint8_t>(1 + rng.below(3));
    const bool cut = rng.below(4) == 0;  // broken off after its FIRST
    for (size_t pos = 0; pos < msg.size();) {
      Bytes chunk;
      uint8_t frag;
      if (pos == 0) {
        frag = 1;
        for (int b = 0; b < 4; ++b) chunk.push_back(static_cast<uint8_t>(msg.size() >> (8 * b)));
      } else {
        frag = msg.size() - pos <= size ? 3 : 2;
      }
      const size_t take = std::min(msg.size() - pos, size - chunk.size());
      chunk.insert(chunk.end(), msg.begin() + static_cast<long>(pos),
                   msg.begin() + static_cast<long>(pos + take));
      pos += take;
      const Bytes dg = native(static_cast<uint8_t>(0x40 | frag << 2), channel, seq++, chunk);
      uint8_t enc[90];
      const size_t n = hwbridge::cobs_encode(dg.data(), dg.size(), enc, sizeof(enc));
      for (size_t i = 0; i < n; ++i) hw.put(enc[i]);
      hw.put(0);
      if (frag == 1) messages.push_back(msg);
      if (cut) break;
    }
    if (rng.below(2)) {  // a reliable datagram or a HEARTBEAT in between
      const Bytes other = native(rng.below(2) ? 0x50 : 0x40, 0, seq++, Bytes(rng.below(9), 7));
      uint8_t enc[40];
      const size_t n = hwbridge::cobs_encode(other.data(), other.size(), enc, sizeof(enc));
      for (size_t i = 0; i < n; ++i) hw.put(enc[i]);
      hw.put(0);
    }
  }
  // The chains' frames under a plain format-2 id (bits 10..7 cleared): transfers of the bytes.
  TransferReceiver<4096, 4> rx(0);
  size_t next_message = 0;
  for (size_t i = 0; i < d.sent.size(); ++i) {
    const Frame& f = d.sent[i];
    if ((f.id & kChainBit) == 0) continue;
    CHECK(((f.id >> 24) & 3) == kBestEffort, "a chain of best-effort fragments");
    Transfer t;
    if (rx.feed(f.id & ~(0xFUL << 7), true, f.data, f.len, 0, &t)) {
      bool found = false;
      while (!found && next_message < messages.size()) {
        found = messages[next_message].size() == t.size &&
                memcmp(messages[next_message].data(), t.payload, t.size) == 0;
        ++next_message;
      }
      CHECK(found, "a chain of %zu bytes that is no message sent", t.size);
      ++g_chains;
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  const uint32_t seed = argc > 1 ? static_cast<uint32_t>(strtoul(argv[1], nullptr, 10)) : 1;
  const double seconds = argc > 2 ? atof(argv[2]) : 2.0;
  Rng rng(seed);
  const time_t start = time(nullptr);
  unsigned long rounds = 0;
  unsigned long delivered = 0;
  while (rounds < 200 || difftime(time(nullptr), start) < seconds) {
    round(rng, rounds % 3 == 0, &delivered);
    if (rounds % 8 == 0) hardware_round(rng);
    if (rounds % 8 == 4) chain_round(rng);
    ++rounds;
    if (difftime(time(nullptr), start) >= seconds && rounds >= 200) break;
  }
  printf("fuzz_can_receiver: seed %u, %lu rounds, %lu transfers delivered, %lu checks; "
         "CanHardware: %lu datagrams read, %lu transfers sent, %lu chains\n",
         seed, rounds, delivered, g_checks, g_read_datagrams, g_sent_transfers, g_chains);
  return 0;
}
