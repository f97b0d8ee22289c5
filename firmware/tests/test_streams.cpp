// The reliable stream end to end, host-native: a ReliableSender and a ReliableReceiver (with
// reassembly) joined by an in-memory link that loses, duplicates, reorders and corrupts frames
// in both directions, driven by a seeded generator and a simulated microsecond clock. Every
// message must arrive exactly once, in order, intact. Also checks the best-effort count
// (frames received + frames counted lost == frames sent) over the same kind of link, and the
// window-1 SingleFrameReceiver against ReliableReceiver<1, N, 0> on random frame sequences.
//
//   test_streams [SEED]
#include <stdio.h>
#include <stdlib.h>

#include <vector>

#include "HwBridge.h"
#include "check.h"

using check::Bytes;
using check::Rng;
using namespace hwbridge;

namespace {

struct Packet {
  uint32_t at;  // delivery time
  Bytes wire;
};

/** One direction of the link: frames as wire bytes, each delayed, maybe lost, duplicated,
 * corrupted; the delays reorder them. */
struct Link {
  Rng* rng;
  unsigned loss, dup, corrupt;  // percent
  uint32_t min_delay, max_delay;
  bool fifo;  // keeps the order (a serial line): no reordering
  std::vector<Packet> queue;
  unsigned sent, lost;
  uint32_t last_at;

  void send(const Bytes& wire, uint32_t now) {
    ++sent;
    if (rng->chance(loss)) {
      ++lost;
      return;
    }
    int copies = rng->chance(dup) ? 2 : 1;
    for (int i = 0; i < copies; ++i) {
      Packet p;
      p.at = now + min_delay + rng->below(max_delay - min_delay + 1);
      if (fifo && !queue.empty() && static_cast<int32_t>(p.at - last_at) < 0) p.at = last_at;
      last_at = p.at;
      p.wire = wire;
      if (rng->chance(corrupt)) p.wire[rng->below(static_cast<uint32_t>(p.wire.size()))] ^= static_cast<uint8_t>(1 + rng->below(255));
      queue.push_back(p);
    }
  }
  /** Bytes of the packets due at now, in delivery order. */
  Bytes take(uint32_t now) {
    Bytes out;
    for (;;) {
      size_t best = queue.size();
      for (size_t i = 0; i < queue.size(); ++i) {
        if (static_cast<int32_t>(now - queue[i].at) >= 0 && (best == queue.size() || static_cast<int32_t>(queue[i].at - queue[best].at) < 0)) best = i;
      }
      if (best == queue.size()) return out;
      out.insert(out.end(), queue[best].wire.begin(), queue[best].wire.end());
      queue.erase(queue.begin() + static_cast<long>(best));
    }
  }
};

Bytes encode(const Frame& f) {
  check::VecSink sink;
  FrameHeader h = {f.type, f.frag, f.channel, f.seq};
  write_frame(sink, h, f.payload, f.size);
  return sink.bytes;
}

Bytes message(uint32_t index, Rng& rng, size_t max_size) {
  size_t size = 4 + rng.below(static_cast<uint32_t>(max_size - 3));
  Bytes m(size);
  for (int i = 0; i < 4; ++i) m[i] = static_cast<uint8_t>(index >> (8 * i));
  for (size_t i = 4; i < size; ++i) m[i] = static_cast<uint8_t>(index * 31 + i * 7);
  return m;
}

template <size_t W, size_t Hold, size_t Mtu, size_t MaxMessage>
void reliable_run(const char* name, uint64_t seed, uint32_t count, unsigned loss, unsigned dup,
                  unsigned corrupt, uint8_t max_retries, bool fifo = false) {
  Rng rng(seed);
  Link ab = {&rng, loss, dup, corrupt, 1000, 25000, fifo, std::vector<Packet>(), 0, 0, 0};
  Link ba = {&rng, loss, dup, corrupt, 1000, 25000, fifo, std::vector<Packet>(), 0, 0, 0};
  const uint8_t isn = static_cast<uint8_t>(rng.below(256));
  ReliableSender<W, Mtu> tx(isn, max_retries);
  ReliableReceiver<W, Mtu, Hold> rx(isn);
  Reassembler<MaxMessage> ra;
  FrameDecoder<Mtu> at_receiver;
  FrameDecoder<8> at_sender;  // ACKs only: a bitmap of at most 8 bytes
  std::vector<Bytes> messages;
  for (uint32_t i = 0; i < count; ++i) messages.push_back(message(i, rng, MaxMessage));
  uint32_t queued = 0, delivered = 0;
  uint32_t now = 0xFFF00000u;  // starts near the wrap of the 32-bit clock
  uint32_t ack_due_since = 0;
  const uint32_t start = now;
  unsigned long steps = 0;
  while (delivered < count) {
    CHECK(++steps < 20000000UL, "%s: not done after %lu steps (%u of %u delivered)", name, steps, delivered, count);
    CHECK(!tx.dead(), "%s (seed %llu): the sender declared the link dead at message %u", name,
          static_cast<unsigned long long>(seed), delivered);
    // Sender: queue the next message when it is taken, send what is due.
    while (queued < count && tx.send(static_cast<uint8_t>(1 + queued % 200), messages[queued].data(), messages[queued].size())) ++queued;
    Frame f;
    while (tx.poll(now, &f)) ab.send(encode(f), now);
    // Receiver.
    Bytes in = ab.take(now);
    for (size_t i = 0; i < in.size(); ++i) {
      if (at_receiver.push(in[i]) != Decoded::Frame) continue;
      const Frame& rf = at_receiver.frame();
      CHECK(rf.type == FrameType::Reliable, "%s: not a reliable frame", name);
      if (!rx.ack_needed()) ack_due_since = now;
      if (rx.receive(rf) != Received::Deliver) continue;
      Frame cur = rf;
      do {
        Message m;
        if (!ra.feed(cur, &m)) continue;
        CHECK(delivered < count, "%s: more messages than sent", name);
        const Bytes& want = messages[delivered];
        CHECK(m.size == want.size() && memcmp(m.data, want.data(), m.size) == 0 &&
                  m.channel == 1 + delivered % 200,
              "%s (seed %llu): message %u wrong (size %zu, expected %zu)", name,
              static_cast<unsigned long long>(seed), delivered, m.size, want.size());
        ++delivered;
      } while (rx.pop(&cur));
    }
    // Delayed ACKs as PROTOCOL.md 2.4 allows: at once when urgent, else within 5 ms.
    if (rx.ack_needed() && (rx.ack_urgent() || static_cast<uint32_t>(now - ack_due_since) >= 5000)) {
      check::VecSink sink;
      rx.write_ack(sink);
      ba.send(sink.bytes, now);
    }
    Bytes acks = ba.take(now);
    for (size_t i = 0; i < acks.size(); ++i) {
      if (at_sender.push(acks[i]) == Decoded::Frame) tx.on_ack(at_sender.frame(), now);
    }
    now += 500;
  }
  CHECK(ra.stats().malformed == 0 && ra.stats().oversize == 0, "%s: reassembly errors", name);
  if (loss) CHECK(tx.stats().retransmits > 0, "%s: lossy but no retransmission", name);
  printf("%s: %u messages in %.1f s simulated; frames sent %u, retransmits %u (fast %u), "
         "duplicates %u, accepted %u, early dropped %u, out of window %u, CRC errors %u, RTO %u us\n",
         name, count, (now - start) / 1e6, static_cast<unsigned>(tx.stats().frames_sent),
         static_cast<unsigned>(tx.stats().retransmits), static_cast<unsigned>(tx.stats().fast_retransmits),
         static_cast<unsigned>(rx.stats().duplicates), static_cast<unsigned>(rx.stats().frames_received),
         static_cast<unsigned>(rx.stats().early_dropped), static_cast<unsigned>(rx.stats().out_of_window),
         static_cast<unsigned>(at_receiver.stats().crc_errors + at_sender.stats().crc_errors),
         static_cast<unsigned>(tx.rtt().rto()));
}

void best_effort_run(uint64_t seed) {
  Rng rng(seed);
  // No corruption here: a corrupted frame counts as a lost one, but one in 65536 passes the
  // CRC with another seq, which would make the exact equation below fail by chance.
  Link link = {&rng, 15, 5, 0, 1000, 20000, false, std::vector<Packet>(), 0, 0, 0};
  BestEffortSender tx(static_cast<uint8_t>(rng.below(256)));
  BestEffortReceiver rx;
  FrameDecoder<16> d;
  const unsigned n = 5000;
  uint32_t now = 0;
  for (unsigned i = 0; i < n; ++i) {
    const uint8_t payload[2] = {static_cast<uint8_t>(i), static_cast<uint8_t>(i >> 8)};
    check::VecSink sink;
    tx.send(sink, 1, payload, 2, 16);
    if (i == 0 || i == n - 1) {
      Packet p = {i == 0 ? now : now + 30000, sink.bytes};  // the first arrives first, the last last
      link.queue.push_back(p);
    } else {
      link.send(sink.bytes, now);
    }
    Bytes in = link.take(now);
    for (size_t k = 0; k < in.size(); ++k) {
      if (d.push(in[k]) == Decoded::Frame) rx.accept(d.frame().seq);
    }
    now += 1000;
  }
  for (int k = 0; k < 100; ++k, now += 1000) {
    Bytes in = link.take(now);
    for (size_t j = 0; j < in.size(); ++j) {
      if (d.push(in[j]) == Decoded::Frame) rx.accept(d.frame().seq);
    }
  }
  const BestEffortStats& s = rx.stats();
  CHECK(s.frames_received + s.frames_lost == n,
        "best effort: received %u + lost %u != sent %u", static_cast<unsigned>(s.frames_received),
        static_cast<unsigned>(s.frames_lost), n);
  printf("best effort: %u sent, %u received, %u counted lost, %u late\n", n,
         static_cast<unsigned>(s.frames_received), static_cast<unsigned>(s.frames_lost),
         static_cast<unsigned>(s.frames_late));
}

/** Both receivers' counters are equal. */
void same_stats(const ReliableReceiverStats& a, const ReliableReceiverStats& b, int step) {
  CHECK(a.frames_received == b.frames_received && a.duplicates == b.duplicates &&
            a.out_of_window == b.out_of_window && a.early_dropped == b.early_dropped &&
            a.acks_sent == b.acks_sent,
        "single-frame receiver: stats differ at step %d", step);
}

/**
 * SingleFrameReceiver (the node's receiver at window 1) against ReliableReceiver<1, N, 0> on
 * seeded random sequences of frames (the expected seq, duplicates, frames ahead, anywhere),
 * ACKs (as bytes on the wire, with and without a lead) and session resets: the same results,
 * state, ACKs and counters at every step.
 */
void single_frame_receiver_run(uint64_t seed) {
  Rng rng(seed);
  const uint8_t isn = static_cast<uint8_t>(rng.below(256));
  ReliableReceiver<1, 16, 0> ref(isn);
  SingleFrameReceiver<16> rx(isn);
  uint8_t payload[16];
  for (int step = 0; step < 20000; ++step) {
    const uint32_t op = rng.below(100);
    if (op < 60) {
      Frame f;
      f.type = FrameType::Reliable;
      f.frag = static_cast<Frag>(rng.below(4));
      f.channel = static_cast<uint8_t>(rng.below(256));
      const uint32_t kind = rng.below(4);
      uint8_t ahead = 0;  // the expected frame
      if (kind == 1) ahead = static_cast<uint8_t>(0 - 1 - rng.below(3));  // just behind
      if (kind == 2) ahead = static_cast<uint8_t>(1 + rng.below(3));      // just ahead
      if (kind == 3) ahead = static_cast<uint8_t>(rng.below(256));        // anywhere
      f.seq = static_cast<uint8_t>(ref.expected() + ahead);
      f.size = rng.below(sizeof payload + 1);
      for (size_t i = 0; i < f.size; ++i) payload[i] = static_cast<uint8_t>(rng.below(256));
      f.payload = payload;
      const Received a = ref.receive(f);
      const Received b = rx.receive(f);
      CHECK(a == b, "single-frame receiver: seq %u gives %d, not %d (step %d)", f.seq,
            static_cast<int>(b), static_cast<int>(a), step);
      Frame pa, pb;
      CHECK(ref.pop(&pa) == rx.pop(&pb), "single-frame receiver: pop differs (step %d)", step);
      if (a == Received::Deliver && rng.chance(20)) {  // taken back: expected again
        CHECK(ref.refuse() && rx.refuse(), "single-frame receiver: refuse refused (step %d)", step);
      }
    } else if (op < 80) {
      const bool lead = rng.chance(50);
      check::VecSink wa, wb;
      const size_t na = ref.write_ack(wa, lead);
      const size_t nb = rx.write_ack(wb, lead);
      CHECK(na == nb && wa.bytes == wb.bytes, "single-frame receiver: ACK %s, not %s (step %d)",
            check::hex(wb.bytes).c_str(), check::hex(wa.bytes).c_str(), step);
    } else if (op < 95) {
      uint8_t ba[kMaxSackBytes], bb[kMaxSackBytes];
      size_t la = 99, lb = 99;
      const uint8_t sa = ref.make_ack(ba, &la);
      const uint8_t sb = rx.make_ack(bb, &lb);
      CHECK(sa == sb && la == lb && lb == 0, "single-frame receiver: make_ack differs (step %d)",
            step);
    } else {
      const uint8_t s = static_cast<uint8_t>(rng.below(256));
      const uint8_t w = static_cast<uint8_t>(rng.below(3));  // 0 and 1 both mean 1
      ref.reset(s, w);
      rx.reset(s, w);
    }
    CHECK(ref.expected() == rx.expected() && ref.ack_needed() == rx.ack_needed() &&
              ref.ack_urgent() == rx.ack_urgent() && ref.held() == rx.held(),
          "single-frame receiver: state differs at step %d", step);
    same_stats(ref.stats(), rx.stats(), step);
  }
  printf("single-frame receiver: 20000 steps as ReliableReceiver<1, N, 0> (%u delivered)\n",
         static_cast<unsigned>(rx.stats().frames_received));
}

/**
 * refuse(): a frame receive() delivered is taken back (expected again, the ACK stops before it,
 * the same frame is delivered when it comes again); a frame released by pop() is not (the peer
 * may know it as held from a bitmap and would never send it again).
 */
void refuse_run() {
  ReliableReceiver<4, 8, 3> rx(10);
  uint8_t payload[1] = {0};
  Frame f;
  f.type = FrameType::Reliable;
  f.frag = Frag::Whole;
  f.channel = 0;
  f.payload = payload;
  f.size = 1;
  f.seq = 10;
  CHECK(rx.receive(f) == Received::Deliver && rx.refuse() && rx.expected() == 10, "refuse of a delivered frame");
  uint8_t bitmap[kMaxSackBytes];
  size_t n = 0;
  CHECK(rx.make_ack(bitmap, &n) == 9 && n == 0, "the ACK after a refusal covers the refused frame");
  CHECK(rx.receive(f) == Received::Deliver && rx.expected() == 11, "the repeated frame is not delivered again");
  f.seq = 12;
  CHECK(rx.receive(f) == Received::Held, "frame 12 not held");
  f.seq = 11;
  CHECK(rx.receive(f) == Received::Deliver, "frame 11 not delivered");
  Frame h;
  CHECK(rx.pop(&h) && h.seq == 12 && !rx.refuse() && rx.expected() == 13, "a popped frame was taken back");
  SingleFrameReceiver<8> one(5);
  f.seq = 5;
  CHECK(one.receive(f) == Received::Deliver && one.refuse() && one.expected() == 5 &&
            one.receive(f) == Received::Deliver && one.expected() == 6,
        "single-frame refuse");
  // reassembly: a WHOLE message is forgotten (its repeat is taken again, not dropped as a
  // duplicate); one of fragments cannot be taken back
  Reassembler<32> re;
  Message m;
  f.seq = 20;
  CHECK(re.feed(f, &m) && re.unfeed() && re.feed(f, &m), "a WHOLE message not taken again after unfeed");
  CHECK(!re.feed(f, &m) && re.stats().duplicates == 1, "a repeat without unfeed was not a duplicate");
  const uint8_t first[6] = {3, 0, 0, 0, 'a', 'b'};
  const uint8_t last[1] = {'c'};
  f.frag = Frag::First;
  f.seq = 21;
  f.payload = first;
  f.size = sizeof first;
  CHECK(!re.feed(f, &m), "a FIRST completed a message");
  f.frag = Frag::Last;
  f.seq = 22;
  f.payload = last;
  f.size = 1;
  CHECK(re.feed(f, &m) && m.size == 3 && !re.unfeed(), "a message of fragments was taken back");
  printf("refuse: a delivered frame is expected again, a popped one is not taken back\n");
}

}  // namespace

int main(int argc, char** argv) {
  const uint64_t seed = argc > 1 ? strtoull(argv[1], nullptr, 10) : 1;
  // The hello-world board: window 1, nothing held, every message one frame.
  reliable_run<1, 0, 64, 64>("window 1", seed, 300, 10, 5, 2, 10);
  // A comfortable board: window 2, fragmented messages up to 192 bytes over MTU 64.
  reliable_run<2, 1, 64, 192>("window 2 fragments", seed + 1, 300, 10, 5, 2, 10);
  // A host-sized window with reordering held; one that drops early frames, on a line that
  // keeps the order (as a serial line does; with reordering such a receiver starves).
  reliable_run<16, 15, 32, 300>("window 16", seed + 2, 600, 10, 5, 2, 10);
  reliable_run<2, 0, 24, 100>("window 2 no hold, in order", seed + 3, 400, 10, 0, 2, 10, true);
  reliable_run<1, 0, 64, 64>("window 1, in order", seed + 6, 300, 10, 0, 2, 10, true);
  // A harsh link: 30 % loss each way, more retries so that the link stays up.
  reliable_run<4, 3, 32, 128>("harsh window 4", seed + 4, 200, 30, 10, 5, 40);
  best_effort_run(seed + 5);
  single_frame_receiver_run(seed + 7);
  refuse_run();
  printf("ok: %lu checks\n", check::count());
  return 0;
}
