// The CAN transport against protocols/vectors/can_frames.json, can_frames_v2.json and
// can_chains.json (fed by can_vectors.py on stdin), then CanHardware with a scripted driver: the
// session's COBS bytes out as transfers (chained ones too, CAN.md 12), the host's transfers in as
// COBS bytes, claims, foreign and oversize traffic counted.
#include <hwbridge/can/can_hardware.h>
#include <hwbridge/can/posix_driver.h>  // compiled with the test's warnings
#include <hwbridge/can/transport.h>
#include <hwbridge/cobs.h>

#include <deque>
#include <iostream>
#include <sstream>

#include "can_check.h"

using namespace hwbridge::can;

namespace {

struct Collect {
  std::vector<std::pair<uint32_t, Bytes> >* out;
  bool operator()(const FrameT<kFdMtu>& f) {
    out->push_back(std::make_pair(f.id, Bytes(f.data, f.data + f.len)));
    return true;
  }
};

typedef TransferReceiver<256, 4> Receiver;

uint32_t counter(const CanStats& s, const std::string& name) {
  if (name == "malformed") return s.malformed;
  if (name == "unexpected") return s.unexpected;
  if (name == "duplicate_frames") return s.duplicate_frames;
  if (name == "duplicate_transfers") return s.duplicate_transfers;
  if (name == "crc_errors") return s.crc_errors;
  if (name == "abandoned") return s.abandoned;
  if (name == "timeouts") return s.timeouts;
  if (name == "oversize") return s.oversize;
  if (name == "foreign") return s.foreign;
  CHECK(false, "unknown counter %s", name.c_str());
  return 0;
}

void chain_vector(const std::string& name, unsigned src, uint32_t host_claim,
                  const std::vector<Bytes>& datagrams,
                  const std::vector<std::pair<uint32_t, Bytes> >& frames);

int vectors() {
  std::string line;
  int n = 0;
  while (std::getline(std::cin, line)) {
    std::istringstream in(line);
    std::string kind;
    in >> kind;
    if (kind == "crc") {
      std::string input, crc;
      in >> input >> crc;
      const Bytes b = from_hex(input);
      CHECK(hwbridge::crc16(b.data(), b.size()) == strtoul(crc.c_str(), nullptr, 16), "crc");
    } else if (kind == "id") {
      unsigned p, k, c, d, s;
      std::string id;
      in >> p >> k >> c >> d >> s >> id;
      const uint32_t want = static_cast<uint32_t>(strtoul(id.c_str(), nullptr, 16));
      CHECK(encode_id(p, k, c, d, s) == want, "encode %s", id.c_str());
      CanId f;
      CHECK(decode_id(want, &f), "decode %s", id.c_str());
      CHECK(f.priority == p && f.kind == k && f.channel == c && f.destination == d &&
                f.source == s,
            "fields of %s", id.c_str());
    } else if (kind == "tx") {
      std::string name, payload_hex;
      unsigned mtu, tid, count;
      in >> name >> mtu >> tid >> payload_hex >> count;
      const Bytes payload = from_hex(payload_hex);
      std::vector<std::pair<uint32_t, Bytes> > got;
      Collect sink = {&got};
      CHECK(send_transfer<kFdMtu>(0x14010005UL, payload.data(), payload.size(), tid, mtu, sink),
            "%s", name.c_str());
      CHECK(got.size() == count, "%s: %zu frames", name.c_str(), got.size());
      Receiver rx(0);
      Transfer t;
      bool done = false;
      std::vector<Bytes> keep;  // a single frame's payload points into its data
      for (unsigned i = 0; i < count; ++i) {
        std::string frame;
        in >> frame;
        CHECK(to_hex(got[i].second) == frame, "%s frame %u: %s", name.c_str(), i,
              to_hex(got[i].second).c_str());
        keep.push_back(from_hex(frame));
        const Bytes& data = keep.back();
        done = rx.feed(0x14010005UL, true, data.data(), data.size(), 1000, &t);
        CHECK(done == (i + 1 == count), "%s: completion at frame %u", name.c_str(), i);
      }
      CHECK(to_hex(t.payload, t.size) == to_hex(payload), "%s: received", name.c_str());
      CHECK(rx.stats.dropped() == 0, "%s: drops", name.c_str());
    } else if (kind == "dg") {
      std::string name, dg_hex;
      unsigned src, dst, mtu, count;
      in >> name >> src >> dst >> mtu >> dg_hex >> count;
      const Bytes dg = from_hex(dg_hex);
      uint8_t k, c;
      kind_of(dg.data(), dg.size(), &k, &c);
      const uint32_t id = encode_id(priority_of(k, c), k, c, dst, src);
      std::vector<std::pair<uint32_t, Bytes> > got;
      Collect sink = {&got};
      TidTable<4> tids;
      CHECK(send_transfer<kFdMtu>(id, dg.data(), dg.size(), tids.next(id), mtu, sink), "%s",
            name.c_str());
      CHECK(got.size() == count, "%s: %zu frames", name.c_str(), got.size());
      Receiver rx(static_cast<uint8_t>(dst));
      Transfer t;
      std::vector<Bytes> keep;
      for (unsigned i = 0; i < count; ++i) {
        std::string frame;
        in >> frame;
        const size_t colon = frame.find(':');
        const uint32_t want_id = static_cast<uint32_t>(strtoul(frame.substr(0, colon).c_str(),
                                                               nullptr, 16));
        CHECK(got[i].first == want_id, "%s id %08lx", name.c_str(),
              static_cast<unsigned long>(got[i].first));
        CHECK(to_hex(got[i].second) == frame.substr(colon + 1), "%s frame %u", name.c_str(), i);
        keep.push_back(from_hex(frame.substr(colon + 1)));
        const Bytes& data = keep.back();
        const bool done = rx.feed(want_id, true, data.data(), data.size(), 5, &t);
        CHECK(done == (i + 1 == count), "%s: completion", name.c_str());
      }
      CHECK(to_hex(t.payload, t.size) == dg_hex && t.id.source == src, "%s: received",
            name.c_str());
    } else if (kind == "id2") {
      unsigned p, k, c, d, src, seq, frag;
      std::string id;
      in >> p >> k >> c >> d >> src >> seq >> frag >> id;
      const uint32_t want = static_cast<uint32_t>(strtoul(id.c_str(), nullptr, 16));
      CHECK(encode_id2(p, k, c, d, src, seq, frag) == want, "encode2 %s", id.c_str());
      CanId f;
      CHECK(decode_id(want, &f) && f.format == kFormat2 && f.priority == p && f.kind == k &&
                f.channel == c && f.destination == d && f.source == src &&
                f.seq_high == (seq >> 5) && f.frag == frag,
            "decode2 %s", id.c_str());
    } else if (kind == "dg2") {
      std::string name, dg_hex;
      unsigned src, dst, mtu, count;
      in >> name >> src >> dst >> mtu >> dg_hex >> count;
      const Bytes dg = from_hex(dg_hex);
      NativeHeader h;
      CHECK(parse_datagram(dg.data(), dg.size(), &h), "%s: a valid datagram", name.c_str());
      const uint32_t id =
          encode_id2(priority_of(h.kind, h.channel), h.kind, h.channel, dst, src, h.seq, h.frag);
      std::vector<std::pair<uint32_t, Bytes> > got;
      Collect sink = {&got};
      CHECK(send_transfer<kFdMtu>(id, dg.data() + 3, dg.size() - 5, h.seq, mtu, sink), "%s",
            name.c_str());
      CHECK(got.size() == count, "%s: %zu frames", name.c_str(), got.size());
      Receiver rx(static_cast<uint8_t>(dst));
      Transfer t;
      std::vector<Bytes> keep;
      for (unsigned i = 0; i < count; ++i) {
        std::string frame;
        in >> frame;
        const size_t colon = frame.find(':');
        const uint32_t want_id = static_cast<uint32_t>(strtoul(frame.substr(0, colon).c_str(),
                                                               nullptr, 16));
        CHECK(got[i].first == want_id, "%s id %08lx", name.c_str(),
              static_cast<unsigned long>(got[i].first));
        CHECK(to_hex(got[i].second) == frame.substr(colon + 1), "%s frame %u", name.c_str(), i);
        keep.push_back(from_hex(frame.substr(colon + 1)));
        const Bytes& data = keep.back();
        const bool done = rx.feed(want_id, true, data.data(), data.size(), 5, &t);
        CHECK(done == (i + 1 == count), "%s: completion", name.c_str());
      }
      uint8_t whole[300];
      const size_t m = rebuild_datagram(t, whole, sizeof(whole));
      CHECK(m == dg.size() && to_hex(whole, m) == dg_hex && t.id.source == src &&
                t.id.format == kFormat2,
            "%s: rebuilt %s", name.c_str(), to_hex(whole, m).c_str());
    } else if (kind == "claim") {
      unsigned src, takes;
      std::string id;
      in >> src >> takes >> id;
      const uint32_t want = static_cast<uint32_t>(strtoul(id.c_str(), nullptr, 16));
      CanId f;
      CHECK(decode_id(want, &f) && f.format == kFormat2 && f.kind == kNode &&
                f.channel == kNodeClaim && f.source == src &&
                ((want & kClaimChains) != 0) == (takes != 0),
            "claim %s", id.c_str());
      // a board's own claims never say it takes chains (it does not: CAN.md 12)
      if (src != 0 && !takes) {
        CHECK(want == encode_id2(kPriorityNode, kNode, kNodeClaim, kHostNode, src, 0, 0),
              "a board's claim %s", id.c_str());
      }
    } else if (kind == "ch") {
      std::string name, claim;
      unsigned src, dst, mtu, ndg, count;
      in >> name >> src >> dst >> mtu >> claim >> ndg;
      std::vector<Bytes> datagrams;
      for (unsigned i = 0; i < ndg; ++i) {
        std::string hex;
        in >> hex;
        datagrams.push_back(from_hex(hex));
      }
      in >> count;
      std::vector<std::pair<uint32_t, Bytes> > frames;
      for (unsigned i = 0; i < count; ++i) {
        std::string frame;
        in >> frame;
        const size_t colon = frame.find(':');
        frames.push_back(std::make_pair(
            static_cast<uint32_t>(strtoul(frame.substr(0, colon).c_str(), nullptr, 16)),
            from_hex(frame.substr(colon + 1))));
      }
      // a board sends chains to the host in classic frames; it does not take chains
      if (src != 0 && mtu == kClassicMtu) {
        chain_vector(name, src, static_cast<uint32_t>(strtoul(claim.c_str(), nullptr, 16)),
                     datagrams, frames);
      }
    } else if (kind == "bad") {
      std::string name, expect;
      unsigned local, count;
      in >> name >> local >> expect >> count;
      Receiver rx(static_cast<uint8_t>(local));
      Transfer t;
      uint32_t delivered = 0;
      for (unsigned i = 0; i < count; ++i) {
        std::string frame;
        in >> frame;
        const size_t a = frame.find(':');
        const size_t b = frame.find(':', a + 1);
        const uint32_t id = static_cast<uint32_t>(strtoul(frame.substr(0, a).c_str(), nullptr, 16));
        const bool ext = frame.substr(a + 1, b - a - 1) == "1";
        const Bytes data = from_hex(frame.substr(b + 1));
        if (rx.feed(id, ext, data.data(), data.size(), 7, &t)) ++delivered;
        if (i + 2 == count) delivered = 0;  // what comes before the last frame may deliver
      }
      CHECK(delivered == 0, "%s: delivered", name.c_str());
      const uint32_t want = expect == "foreign" ? rx.stats.dropped() + 1 : rx.stats.dropped();
      CHECK(counter(rx.stats, expect) == 1, "%s: %s", name.c_str(), expect.c_str());
      CHECK(want == 1, "%s: other drops", name.c_str());
    } else if (!kind.empty()) {
      CHECK(false, "unknown line %s", kind.c_str());
    }
    ++n;
  }
  return n;
}

// A scripted driver: frames sent are kept, frames to receive are queued by the test.
struct ScriptDriver {
  std::deque<Frame> inbox;
  std::vector<Frame> sent;
  uint32_t now;
  bool refuse;
  ScriptDriver() : now(1000), refuse(false) {}
  bool begin(uint8_t) { return true; }
  bool receive(Frame* f) {
    if (inbox.empty()) return false;
    *f = inbox.front();
    inbox.pop_front();
    return true;
  }
  bool send(const Frame& f, uint8_t) {
    if (refuse) return false;
    sent.push_back(f);
    return true;
  }
  uint32_t micros() { return now; }
  uint32_t seed() { return 42; }
};

typedef CanHardware<ScriptDriver, 72, 2, 160> Hw;

void queue_transfer(Hw& hw, uint32_t id, const Bytes& payload, uint8_t tid) {
  struct Q {
    ScriptDriver* d;
    bool operator()(const Frame& f) {
      d->inbox.push_back(f);
      return true;
    }
  } q = {&hw.driver()};
  send_transfer<kClassicMtu>(id, payload.data(), payload.size(), tid, kClassicMtu, q);
}

Bytes read_all(Hw& hw) {
  Bytes out;
  for (int c = hw.read(); c >= 0; c = hw.read()) out.push_back(static_cast<uint8_t>(c));
  return out;
}

const uint8_t kHostUid[6] = {0xA0, 0xA1, 0xA2, 0xA3, 0xA4, 0xA5};

void write_datagram(Hw& hw, const Bytes& datagram) {
  uint8_t enc[600];
  const size_t n = hwbridge::cobs_encode(datagram.data(), datagram.size(), enc, sizeof(enc));
  for (size_t i = 0; i < n; ++i) hw.put(enc[i]);
  hw.put(0);
}

std::string frames_hex(const std::vector<Frame>& frames) {
  std::string out;
  for (size_t i = 0; i < frames.size(); ++i) {
    char id[12];
    snprintf(id, sizeof(id), "%08lx:", static_cast<unsigned long>(frames[i].id));
    out += id + to_hex(frames[i].data, frames[i].len) + " ";
  }
  return out;
}

/** A chain vector through CanHardware: the host claims with bit 11, the session writes the
 * datagrams, the driver must get exactly the vector's frames. */
void chain_vector(const std::string& name, unsigned src, uint32_t host_claim,
                  const std::vector<Bytes>& datagrams,
                  const std::vector<std::pair<uint32_t, Bytes> >& frames) {
  Hw hw;
  hw.setNode(static_cast<uint8_t>(src));
  CHECK(hw.init(115200), "init");
  queue_transfer(hw, host_claim, Bytes(kHostUid, kHostUid + 6), 0);
  CHECK(hw.read() == -1 && hw.hostTakesChains(), "%s: the host takes chains", name.c_str());
  ScriptDriver& d = hw.driver();
  d.sent.clear();
  for (size_t i = 0; i < datagrams.size(); ++i) write_datagram(hw, datagrams[i]);
  std::string want;
  for (size_t i = 0; i < frames.size(); ++i) {
    char id[12];
    snprintf(id, sizeof(id), "%08lx:", static_cast<unsigned long>(frames[i].first));
    want += id + to_hex(frames[i].second) + " ";
  }
  CHECK(frames_hex(d.sent) == want, "%s: sent %s", name.c_str(), frames_hex(d.sent).c_str());
  CHECK(hw.stats.chain_breaks == 0 && hw.stats.tx_errors == 0, "%s: no breaks", name.c_str());
}

/** Fragments of one best-effort message (PROTOCOL.md 1.9) as bare datagrams. */
std::vector<Bytes> fragments(uint8_t channel, uint8_t seq, size_t len, size_t size) {
  std::vector<Bytes> out;
  size_t pos = 0;
  while (pos < len || out.empty()) {
    Bytes d;
    uint8_t frag = 0;
    size_t take = len;
    if (len > size) {
      frag = pos == 0 ? 1 : (len - pos <= size ? 3 : 2);
      take = pos == 0 ? size - 4 : (len - pos < size ? len - pos : size);
    }
    d.push_back(static_cast<uint8_t>(0x40 | frag << 2));
    d.push_back(channel);
    d.push_back(static_cast<uint8_t>(seq + out.size()));
    if (frag == 1) {
      for (int k = 0; k < 4; ++k) d.push_back(static_cast<uint8_t>(len >> (8 * k)));
    }
    for (size_t i = 0; i < take; ++i) d.push_back(static_cast<uint8_t>(pos + i));
    pos += take;
    const uint16_t crc = hwbridge::crc16(d.data(), d.size());
    d.push_back(static_cast<uint8_t>(crc & 0xFF));
    d.push_back(static_cast<uint8_t>(crc >> 8));
    out.push_back(d);
  }
  return out;
}

/** Chains (CAN.md 12) only to a host whose claims take them, not with setChains(false); a chain
 * broken off by another datagram or by the driver is counted and the next message goes; chained
 * frames sent to the board are malformed there (a board does not take chains). */
void hardware_chains() {
  const uint32_t claim2 = encode_id2(3, kNode, 1, 0, 0, 0, 0);
  const uint32_t claim3 = claim2 | kClaimChains;
  const std::vector<Bytes> msg = fragments(1, 0x10, 320, 64);  // an Imu: 6 fragments
  CHECK(msg.size() == 6, "fragments");
  for (int mode = 0; mode < 2; ++mode) {  // a version-2 host; setChains(false)
    Hw hw;
    hw.setNode(5);
    if (mode == 1) hw.setChains(false);
    CHECK(hw.init(115200), "init");
    queue_transfer(hw, mode == 0 ? claim2 : claim3, Bytes(kHostUid, kHostUid + 6), 0);
    CHECK(hw.read() == -1 && !hw.hostTakesChains(), "no chains (%d)", mode);
    hw.driver().sent.clear();
    for (size_t i = 0; i < msg.size(); ++i) write_datagram(hw, msg[i]);
    CHECK(hw.driver().sent.size() == 51 && hw.stats.tx_chains == 0, "51 frames (%d): %zu", mode,
          hw.driver().sent.size());
  }
  Hw hw;
  hw.setNode(5);
  CHECK(hw.init(115200), "init");
  ScriptDriver& d = hw.driver();
  queue_transfer(hw, claim3, Bytes(kHostUid, kHostUid + 6), 0);
  CHECK(hw.read() == -1 && hw.hostTakesChains(), "chains");
  d.sent.clear();
  const uint32_t transfers = hw.stats.tx_transfers;
  for (size_t i = 0; i < msg.size(); ++i) write_datagram(hw, msg[i]);
  CHECK(d.sent.size() == 46 && hw.stats.tx_chains == 1 && hw.stats.tx_transfers == transfers + 1,
        "46 frames: %zu", d.sent.size());
  // broken off by a HEARTBEAT of the same stream after two fragments: it goes as usual
  d.sent.clear();
  const std::vector<Bytes> next = fragments(1, 0x16, 320, 64);
  write_datagram(hw, next[0]);
  write_datagram(hw, next[1]);
  Bytes hb = from_hex("40001c02");
  const uint16_t hb_crc = hwbridge::crc16(hb.data(), hb.size());
  hb.push_back(static_cast<uint8_t>(hb_crc & 0xFF));
  hb.push_back(static_cast<uint8_t>(hb_crc >> 8));
  write_datagram(hw, hb);
  CHECK(hw.stats.chain_breaks == 1 && d.sent.back().id == encode_id2(2, 0, 0, 0, 5, 0x1c, 0) &&
            d.sent.back().len == 2,
        "broken off: %s", frames_hex(d.sent).c_str());
  // the rest of the broken message: ordinary transfers (the host drops them as orphans)
  const size_t before = d.sent.size();
  write_datagram(hw, next[2]);
  CHECK(d.sent.size() == before + 10 && hw.stats.tx_chains == 2, "orphan fragment");
  // the driver refuses a frame mid-chain: counted, the next message chains again
  d.sent.clear();
  const std::vector<Bytes> third = fragments(1, 0x20, 320, 64);
  write_datagram(hw, third[0]);
  d.refuse = true;
  write_datagram(hw, third[1]);
  d.refuse = false;
  for (size_t i = 2; i < third.size(); ++i) write_datagram(hw, third[i]);
  CHECK(hw.stats.tx_errors == 1, "refused: %lu", static_cast<unsigned long>(hw.stats.tx_errors));
  d.sent.clear();
  const std::vector<Bytes> fourth = fragments(1, 0x26, 320, 64);
  Bytes rel = from_hex("5003c82a000000");  // a reliable datagram between two fragments
  const uint16_t rel_crc = hwbridge::crc16(rel.data(), rel.size());
  rel.push_back(static_cast<uint8_t>(rel_crc & 0xFF));
  rel.push_back(static_cast<uint8_t>(rel_crc >> 8));
  const uint32_t breaks = hw.stats.chain_breaks;
  for (size_t i = 0; i < fourth.size(); ++i) {
    write_datagram(hw, fourth[i]);
    if (i == 2) write_datagram(hw, rel);
  }
  size_t chained = 0;
  for (size_t i = 0; i < d.sent.size(); ++i) chained += (d.sent[i].id & kChainBit) != 0;
  CHECK(d.sent.size() == 47 && chained == 46 && hw.stats.chain_breaks == breaks,
        "chains again, a reliable datagram beside: %zu", d.sent.size());
  // a chain sent to the board: its receiver drops the frames as malformed
  const uint32_t malformed = hw.rxStats().malformed;
  queue_transfer(hw, (encode_id2(5, 0, 1, 5, 0, 0x10, 0) | kChainBit | (1UL << 8)),
                 Bytes(40, 7), 0x10);
  CHECK(hw.read() == -1 && hw.rxStats().malformed == malformed + 6 &&
            hw.rxStats().transfers == 1,
        "a chain to the board: %u malformed", hw.rxStats().malformed - malformed);
}

/** A board under a host that claims in format 1 (older host software): it speaks format 1. */
void hardware() {
  Hw hw;
  hw.setNode(5);
  CHECK(hw.init(115200), "init");
  CHECK(hw.read() == -1, "nothing yet");
  // The first poll sent a claim in format 2: NODE kind, channel 1, priority 3, to 0, from 5.
  ScriptDriver& d = hw.driver();
  CHECK(d.sent.size() == 1 && d.sent[0].id == encode_id2(3, kNode, 1, 0, 5, 0, 0) &&
            d.sent[0].len == 7,
        "claim");
  CHECK(hw.format() == kFormat2, "format 2 first");
  d.sent.clear();
  // The host claims in format 1: the board speaks format 1 from now on.
  queue_transfer(hw, encode_id(3, kNode, 1, 0, 0), Bytes(kHostUid, kHostUid + 6), 0);
  CHECK(hw.read() == -1 && hw.format() == kFormat1 && hw.stats.format_changes == 1,
        "format 1 after the host's claim");

  // The session writes a HEARTBEAT datagram, COBS-framed: one single-frame transfer.
  const Bytes hb = from_hex("400009028670");
  uint8_t enc[16];
  size_t n = hwbridge::cobs_encode(hb.data(), hb.size(), enc, sizeof(enc));
  for (size_t i = 0; i < n; ++i) hw.put(enc[i]);
  CHECK(d.sent.empty(), "nothing before the delimiter");
  hw.put(0);
  CHECK(d.sent.size() == 1 && d.sent[0].id == 0x08000005UL, "heartbeat id");
  CHECK(to_hex(d.sent[0].data, d.sent[0].len) == "400009028670e0", "heartbeat frame");
  // A reliable datagram with zeros inside: two frames, tid 0 then 1 on the next.
  const Bytes rel = from_hex("5003c82a000000c9bb");
  n = hwbridge::cobs_encode(rel.data(), rel.size(), enc, sizeof(enc));
  for (int round = 0; round < 2; ++round) {
    for (size_t i = 0; i < n; ++i) hw.put(enc[i]);
    hw.put(0);
  }
  CHECK(d.sent.size() == 5, "frames %zu", d.sent.size());
  CHECK(to_hex(d.sent[1].data, d.sent[1].len) == "5003c82a000000a0", "reliable frame 1");
  CHECK(to_hex(d.sent[2].data, d.sent[2].len) == "c9bb30ee40", "reliable frame 2");
  CHECK((d.sent[3].data[7] & kTidMask) == 1, "the next transfer id");
  CHECK(hw.stats.tx_transfers == 4, "transfers");
  // Too long a datagram is dropped and counted, and the next one goes.
  for (int i = 0; i < 100; ++i) hw.put(1);
  hw.put(0);
  CHECK(hw.stats.tx_oversize == 1, "oversize out");
  // A refusing driver: counted.
  d.refuse = true;
  for (size_t i = 0; i < n; ++i) hw.put(enc[i]);
  hw.put(0);
  CHECK(hw.stats.tx_errors == 1, "tx errors");
  d.refuse = false;

  // The host's transfers to node 5 come out COBS-encoded and delimited.
  const Bytes ack = from_hex("6000110000837c");
  queue_transfer(hw, encode_id(1, kAck, 0, 5, 0), ack, 0);
  const Bytes big = from_hex("400100000102030405060708090a0b0c0d0e0f101112131415161718191a1b");
  queue_transfer(hw, encode_id(5, kBestEffort, 1, 5, 0), big, 0);
  // Another board's traffic, a transfer to node 6 and one from node 9 to us: none of it ours.
  queue_transfer(hw, encode_id(5, kBestEffort, 1, 0, 6), big, 0);
  queue_transfer(hw, encode_id(5, kBestEffort, 1, 6, 0), big, 0);
  queue_transfer(hw, encode_id(5, kBestEffort, 1, 5, 9), big, 0);
  Bytes want;
  for (int k = 0; k < 2; ++k) {
    const Bytes& b = k == 0 ? ack : big;
    uint8_t tmp[80];
    const size_t m = hwbridge::cobs_encode(b.data(), b.size(), tmp, sizeof(tmp));
    want.insert(want.end(), tmp, tmp + m);
    want.push_back(0);
  }
  Bytes got;
  for (int spins = 0; spins < 10; ++spins) {
    const Bytes part = read_all(hw);
    got.insert(got.end(), part.begin(), part.end());
  }
  CHECK(to_hex(got) == to_hex(want), "read %s", to_hex(got).c_str());
  CHECK(hw.rxStats().foreign > 0 && hw.stats.rx_ignored == 1, "foreign %u ignored %u",
        hw.rxStats().foreign, hw.stats.rx_ignored);
  // A claim of node 5 by another unique id: a conflict; our own uid: none.
  const uint8_t other[6] = {1, 2, 3, 4, 5, 6};
  queue_transfer(hw, encode_id(3, kNode, 1, 0, 5), Bytes(other, other + 6), 0);
  queue_transfer(hw, encode_id(3, kNode, 1, 0, 5), Bytes(hw.uid(), hw.uid() + 6), 1);
  read_all(hw);
  CHECK(hw.ownConflicts() == 1, "conflicts %u", hw.ownConflicts());
  // Claims every second.
  d.sent.clear();
  d.now += 1000001UL;
  read_all(hw);
  CHECK(d.sent.size() == 1 && d.sent[0].id == encode_id(3, kNode, 1, 0, 5), "second claim");
  // A full read buffer drops whole datagrams (counted), never a part of one.
  for (uint8_t i = 0; i < 8; ++i) queue_transfer(hw, encode_id(5, 0, 1, 5, 0), big, i);
  for (int i = 0; i < 4; ++i) hw.poll();
  CHECK(hw.stats.rx_overflow > 0, "overflow");
  got = read_all(hw);
  CHECK(!got.empty() && got.back() == 0, "whole datagrams");
}

/** A board under a format-2 host: no native header or CRC-16 on the bus, datagrams rebuilt
 * whole for the session, a resent reliable datagram delivered again, bad datagrams refused. */
void hardware_format2() {
  Hw hw;
  hw.setNode(5);
  CHECK(hw.init(115200), "init");
  ScriptDriver& d = hw.driver();
  queue_transfer(hw, encode_id2(3, kNode, 1, 0, 0, 0, 0), Bytes(kHostUid, kHostUid + 6), 0);
  CHECK(hw.read() == -1 && hw.format() == kFormat2 && hw.stats.format_changes == 0, "format 2");
  d.sent.clear();
  // HEARTBEAT 40 00 09 | 02 | CRC: one frame of its payload byte and the tail byte (seq 9).
  const Bytes hb = from_hex("400009028670");
  uint8_t enc[80];
  size_t n = hwbridge::cobs_encode(hb.data(), hb.size(), enc, sizeof(enc));
  for (size_t i = 0; i < n; ++i) hw.put(enc[i]);
  hw.put(0);
  CHECK(d.sent.size() == 1 && d.sent[0].id == encode_id2(2, kBestEffort, 0, 0, 5, 9, 0),
        "heartbeat id %08lx", static_cast<unsigned long>(d.sent[0].id));
  CHECK(to_hex(d.sent[0].data, d.sent[0].len) == "02e9", "heartbeat frame %s",
        to_hex(d.sent[0].data, d.sent[0].len).c_str());
  // A reliable datagram, seq 0xc8: 4 payload bytes, one frame, the seq split id/tail.
  const Bytes rel = from_hex("5003c82a000000c9bb");
  n = hwbridge::cobs_encode(rel.data(), rel.size(), enc, sizeof(enc));
  for (size_t i = 0; i < n; ++i) hw.put(enc[i]);
  hw.put(0);
  CHECK(d.sent.size() == 2 && d.sent[1].id == encode_id2(4, kReliable, 3, 0, 5, 0xC8, 0) &&
            to_hex(d.sent[1].data, d.sent[1].len) == "2a000000e8",
        "reliable frame %s", to_hex(d.sent[1].data, d.sent[1].len).c_str());
  // A datagram with a wrong CRC-16 is not sent (format 2 would make it look right).
  Bytes broken = rel;
  broken.back() ^= 1;
  n = hwbridge::cobs_encode(broken.data(), broken.size(), enc, sizeof(enc));
  for (size_t i = 0; i < n; ++i) hw.put(enc[i]);
  hw.put(0);
  CHECK(d.sent.size() == 2 && hw.stats.tx_oversize == 1, "bad datagram refused");
  // The host's reliable datagram to node 5, twice (a resend): rebuilt whole both times.
  Bytes big = from_hex("500161");
  for (uint8_t i = 0; i < 20; ++i) big.push_back(i);
  const uint16_t crc = hwbridge::crc16(big.data(), big.size());
  big.push_back(static_cast<uint8_t>(crc & 0xFF));
  big.push_back(static_cast<uint8_t>(crc >> 8));
  const uint32_t id = encode_id2(4, kReliable, 1, 5, 0, 0x61, 0);
  const Bytes body(big.begin() + 3, big.end() - 2);
  queue_transfer(hw, id, body, 0x61 & kTidMask);
  queue_transfer(hw, id, body, 0x61 & kTidMask);
  Bytes want;
  for (int k = 0; k < 2; ++k) {
    const size_t m = hwbridge::cobs_encode(big.data(), big.size(), enc, sizeof(enc));
    want.insert(want.end(), enc, enc + m);
    want.push_back(0);
  }
  Bytes got;
  for (int spins = 0; spins < 10; ++spins) {
    const Bytes part = read_all(hw);
    got.insert(got.end(), part.begin(), part.end());
  }
  CHECK(to_hex(got) == to_hex(want), "read %s", to_hex(got).c_str());
  CHECK(hw.rxStats().dropped() == 0 && hw.rxStats().transfers == 3, "no drops");
  // A format-1 transfer from the host is still understood (the host's answer to old firmware).
  const Bytes ack = from_hex("6000110000837c");
  queue_transfer(hw, encode_id(1, kAck, 0, 5, 0), ack, 0);
  got = read_all(hw);
  const size_t m = hwbridge::cobs_encode(ack.data(), ack.size(), enc, sizeof(enc));
  CHECK(to_hex(got) == to_hex(enc, m) + "00", "format-1 ack read");
  CHECK(hw.format() == kFormat2, "still format 2 (only the host's claims choose)");
}

/** setFormat(kFormat1): a board as CAN.md version-1 firmware, whatever the host claims in. */
void hardware_version1() {
  Hw hw;
  hw.setNode(5);
  hw.setFormat(kFormat1);
  CHECK(hw.init(115200), "init");
  ScriptDriver& d = hw.driver();
  CHECK(hw.read() == -1 && d.sent.size() == 1 && d.sent[0].id == encode_id(3, kNode, 1, 0, 5),
        "a format-1 claim");
  queue_transfer(hw, encode_id2(3, kNode, 1, 0, 0, 0, 0), Bytes(kHostUid, kHostUid + 6), 0);
  const Bytes body = from_hex("2a000000");
  queue_transfer(hw, encode_id2(4, kReliable, 3, 5, 0, 0xc8, 0), body, 0xc8 & kTidMask);
  CHECK(hw.read() == -1 && hw.format() == kFormat1 && hw.rxStats().malformed == 2 &&
            hw.rxStats().transfers == 0,
        "format 2 refused: %u malformed", hw.rxStats().malformed);
}

}  // namespace

int main() {
  const int n = vectors();
  CHECK(n >= 30, "only %d vector lines", n);
  hardware();
  hardware_format2();
  hardware_version1();
  hardware_chains();
  printf("test_can_vectors: %d vector lines, %lu checks passed\n", n, g_checks);
  return 0;
}
