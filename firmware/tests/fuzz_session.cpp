// Seeded, time-bounded fuzzing of the board session's receive path (hwbridge/node.h): a board
// connected by the golden handshake gets valid frames with random fields and control payloads
// (built from the messages a host sends, then mutated), random bytes, truncated and spliced
// frames, while the test publishes, logs, asks for parameters and moves the clock (link losses
// included). Guard words around the node catch a write past any of its buffers; ASan/UBSan the
// rest. The session's invariants are checked after every input.
//
//   python3 firmware/tests/session_vectors.py | BUILD/fuzz_session SEED SECONDS
#include <time.h>

#include "session_harness.h"

using harness::Bytes;
using harness::Host;
using hwbridge::FrameType;

namespace {

const uint32_t kGuard = 0xA5C3E7F1UL;

struct Guarded {
  uint32_t before[8];
  harness::GoldenBoard board;
  uint32_t after[8];
  Guarded() : board() {
    for (int i = 0; i < 8; ++i) before[i] = after[i] = kGuard;
  }
  void check() const {
    for (int i = 0; i < 8; ++i) {
      CHECK(before[i] == kGuard && after[i] == kGuard, "guard word %d overwritten", i);
    }
  }
};

int g_params = 0;
void on_param(const hwbridge::ParamValue& v) {
  ++g_params;
  char buf[8];
  for (uint16_t i = 0; i < v.count() && i < 4; ++i) {
    (void)v.asInt(i);
    (void)v.asFloat(i);
    (void)v.asString(buf, sizeof(buf), i);
  }
}

/** Payloads a host sends, as seeds for mutation. */
std::vector<Bytes> seeds(const harness::Transcript& tr) {
  std::vector<Bytes> out;
  for (size_t i = 0; i < tr.frames.size(); ++i) {
    if (tr.frames[i].second.first != 'h') continue;
    std::vector<std::pair<hwbridge::Frame, Bytes> > fr = harness::frames_of(tr.frames[i].second.second);
    for (size_t k = 0; k < fr.size(); ++k) out.push_back(fr[k].second);
  }
  out.push_back(Bytes{0x31, 0, 0, 0, 1, 'a', 0x84, 2, 0, 1, 0, 'x', 0, 0});  // a string list
  out.push_back(Bytes{0x31, 0, 0, 0, 1, 'a', 0x83, 3, 0, 0, 0, 0x80, 0x3f});
  out.push_back(Bytes{0x13, 2, 1, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 'x'});
  out.push_back(Bytes{0x40, 1, 'h', 'i'});
  out.push_back(Bytes{0x21, 3, 1, 0, 0});
  return out;
}

Bytes mutate(Bytes b, check::Rng& rng) {
  const int n = static_cast<int>(rng.below(4));
  for (int i = 0; i < n; ++i) {
    switch (rng.below(5)) {
      case 0:
        if (!b.empty()) b[rng.below(b.size())] ^= static_cast<uint8_t>(1u << rng.below(8));
        break;
      case 1:
        if (!b.empty()) b[rng.below(b.size())] = static_cast<uint8_t>(rng.below(256));
        break;
      case 2:
        if (!b.empty()) b.resize(rng.below(b.size() + 1));
        break;
      case 3:
        b.push_back(static_cast<uint8_t>(rng.below(256)));
        break;
      default:
        for (size_t k = rng.below(80); k; --k) b.push_back(static_cast<uint8_t>(rng.below(256)));
    }
  }
  return b;
}

}  // namespace

int main(int argc, char** argv) {
  const uint64_t seed = argc > 1 ? strtoull(argv[1], nullptr, 10) : 1;
  const double seconds = argc > 2 ? atof(argv[2]) : 3;
  harness::Transcript tr;
  tr.read(stdin);
  const std::vector<Bytes> corpus = seeds(tr);
  check::Rng rng(seed);
  const clock_t end = clock() + static_cast<clock_t>(seconds * CLOCKS_PER_SEC);
  unsigned long inputs = 0, boards = 0, sessions = 0;
  while (clock() < end) {
    Guarded* g = new Guarded();
    harness::GoldenBoard& b = g->board;
    Host host;
    harness::connect(b, tr, &host);
    ++boards;
    b.hw().step_us = 50;  // blocking sends spin on the clock
    double t = 10.0;
    for (int round = 0; round < 400 && b.node.stats().sessions < 3; ++round) {
      t = b.hw().clock / 1e6;
      t += rng.below(4) == 0 ? rng.below(1000) / 1000.0 : rng.below(20) / 1000.0;
      Bytes in;
      const unsigned kind = static_cast<unsigned>(rng.below(10));
      if (kind < 6) {  // a valid frame around the expected numbers
        const Bytes& base = corpus[rng.below(corpus.size())];
        const Bytes payload = rng.below(3) ? mutate(base, rng) : base;
        const FrameType type = static_cast<FrameType>(rng.below(3));
        const uint8_t channel = static_cast<uint8_t>(rng.below(4) ? 0 : rng.below(4));
        uint8_t seq = type == FrameType::Reliable ? host.rel_seq : host.be_seq;
        if (rng.below(4) == 0) seq = static_cast<uint8_t>(rng.below(256));
        const hwbridge::Frag frag = static_cast<hwbridge::Frag>(rng.below(5) ? 0 : rng.below(4));
        in = host.frame(type, channel, seq, payload, frag);
        if (type == FrameType::Reliable && seq == host.rel_seq) ++host.rel_seq;
        if (type == FrameType::BestEffort) host.be_seq = static_cast<uint8_t>(seq + 1);
        if (rng.below(8) == 0) in = mutate(in, rng);
      } else if (kind < 7) {  // random bytes
        for (size_t k = rng.below(300); k; --k) in.push_back(static_cast<uint8_t>(rng.below(256)));
      } else if (kind < 8) {  // an ACK of what the board sent
        in = host.ack(static_cast<uint8_t>(rng.below(256)));
      } else {  // the board acts
        const harness::Raw m;
        switch (rng.below(4)) {
          case 0: b.chatter.publish(m); break;
          case 1: b.node.logInfo("fuzz"); break;
          case 2: b.node.requestParam("p", static_cast<uint8_t>(rng.below(256)), &on_param, rng.below(2)); break;
          default: b.node.runTimers();
        }
      }
      b.input(in, t);
      if (rng.below(3) == 0) b.timers(t);
      ++inputs;
      g->check();
      const hwbridge::NodeStats& s = b.node.stats();
      CHECK(!b.node.connected() || s.sessions >= 1, "connected without a session");
    }
    sessions += b.node.stats().sessions;
    delete g;
  }
  printf("fuzz_session: seed %llu, %lu inputs, %lu boards, %lu sessions, %d parameter answers\n",
         static_cast<unsigned long long>(seed), inputs, boards, sessions, g_params);
  return 0;
}
