// What the session tests share: a scripted Hardware (bytes in, bytes out, a clock the test
// sets), raw message types, the golden table of PROTOCOL.md 2.12, a small scripted host that
// writes frames, and the replay of the transcript up to CONNECTED.
#ifndef HWBRIDGE_TESTS_SESSION_HARNESS_H
#define HWBRIDGE_TESTS_SESSION_HARNESS_H

#include <map>
#include <string>
#include <utility>
#include <vector>

#include "check.h"

// The golden board's identity (PROTOCOL.md 2.12): example values, as
// tests/protocols/test_native_session.py's GOLDEN_IDENTITY, not this build's hashes.
#define HWBRIDGE_SCHEMA_HASH "5c0e1a2b"
#define HWBRIDGE_MSGS_HASH "7d3f9e46"
#define HWBRIDGE_LIBRARY_VERSION "0.1.0"
#define HWBRIDGE_FIRMWARE_NAME "golden"
#include <hwbridge/node.h>
#include <std_msgs/String.h>
#include <std_srvs/Trigger.h>

namespace harness {

using check::Bytes;

/** The Hardware concept over memory: the test feeds input and takes output. With step_us, every
 * micros() call advances the clock (blocking calls spin on it). */
struct FakeHardware {
  Bytes in;
  size_t pos = 0;
  Bytes out;
  uint32_t clock = 0;
  uint32_t step_us = 0;
  bool init(uint32_t) { return true; }
  int read() { return pos < in.size() ? in[pos++] : -1; }
  void put(uint8_t b) { out.push_back(b); }
  void flush() {}
  uint32_t micros() {
    const uint32_t t = clock;
    clock += step_us;
    return t;
  }
  uint32_t seed() { return 0x1234567; }
  void feed(const Bytes& b) { in.insert(in.end(), b.begin(), b.end()); }
  Bytes take() {
    Bytes o;
    o.swap(out);
    return o;
  }
};

/** The device defaults of the golden transcript (DeviceConfig: time sync every 5 s), with a
 * transmit buffer for the 70-byte message of example I. */
struct GoldenProfile {
  static const uint16_t kMtu = 64;
  static const uint16_t kMaxMessage = 64;
  static const uint8_t kWindow = 1;
#ifdef HWBRIDGE_TEST_HELLO
  static const uint16_t kTxBuffer = 64;  // fits the MTU: no fragmentation, the one-slot sender
#else
  static const uint16_t kTxBuffer = 80;
#endif
  static const uint8_t kFeatures = 3;
  static const uint16_t kTimeSyncMs = 5000;
  static const uint16_t kParamTimeoutMs = 2000;
  static const uint16_t kServiceTimeoutMs = 5000;
#if defined(HWBRIDGE_TEST_FIXED_RTO) || defined(HWBRIDGE_TEST_HELLO)
  static const bool kFixedRto = true;  // the hello-world simplification (same bytes on a clean link)
#else
  static const bool kFixedRto = false;
#endif
};

typedef hwbridge::NodeHandle_<FakeHardware, GoldenProfile> Node;

/** A message given as its serialized bytes, announced as std_msgs/String. */
struct Raw {
  const uint8_t* p = nullptr;
  size_t n = 0;
  void write(hwbridge::msg::Writer& w) const {
    for (size_t i = 0; i < n; ++i) w.u8(p[i]);
  }
  bool deserialize(const uint8_t* b, size_t len) {
    p = b;
    n = len;
    return true;
  }
  static const char* type_name() { return "std_msgs/String"; }
  static const char* md5sum() { return "992ce8a1687cec8c8bd883ec73ca41d1"; }
  static const uint8_t* md5_bytes() {
    static const uint8_t md5[16] = {0x99, 0x2c, 0xe8, 0xa1, 0x68, 0x7c, 0xec, 0x8c,
                                    0x8b, 0xd8, 0x83, 0xec, 0x73, 0xca, 0x41, 0xd1};
    return md5;
  }
};

inline void on_reset(const std_srvs::TriggerRequest&, std_srvs::TriggerResponse& res) {
  res.success = true;
  res.message.assign("ok");
}

/** The golden board: "uno", unique id 01..08, firmware 0.1.0 (and the identity above), /chatter
 * and /reset. */
struct GoldenBoard {
  Node node;
  hwbridge::Publisher<Raw> chatter{"/chatter"};
  hwbridge::ServiceServer<std_srvs::Trigger> reset{"/reset", &on_reset};
  uint8_t uid[8] = {1, 2, 3, 4, 5, 6, 7, 8};

  GoldenBoard() : node() {}
  void start(double t) {
    hw().clock = us(t);
    node.setIdentity(0xcafef00dUL, 0);
    node.setUniqueId(uid, 8);
    node.advertise(chatter);
    node.advertiseService(reset);
    node.begin("uno", "0.1.0");
  }
  FakeHardware& hw() { return node.getHardware(); }
  static uint32_t us(double t) { return static_cast<uint32_t>(t * 1e6 + 0.5); }
  /** Feeds bytes at time t and handles them (input only, as DeviceSession.receive_data). */
  Bytes input(const Bytes& b, double t) {
    hw().clock = us(t);
    hw().feed(b);
    node.processInput();
    return hw().take();
  }
  /** Runs the timers at time t (DeviceSession.tick). */
  Bytes timers(double t) {
    hw().clock = us(t);
    node.runTimers();
    return hw().take();
  }
};

/** The golden transcript, read from stdin (session_vectors.py). */
struct Transcript {
  std::vector<std::pair<std::string, std::pair<char, Bytes> > > frames;
  size_t golden = 0;  ///< the frames of the transcript itself (T lines); the rest are extra vectors (X)

  void read(FILE* f) {
    char kind[4], name[128], dir[4], hex[1024];
    while (fscanf(f, "%3s %127s %3s %1023s", kind, name, dir, hex) == 4) {
      frames.push_back(std::make_pair(std::string(name), std::make_pair(dir[0], check::unhex(hex))));
      if (kind[0] == 'T') ++golden;
    }
    CHECK(frames.size() > 30, "no transcript on stdin (%zu frames)", frames.size());
  }
  /** The bytes of the frames called name or name[i], in order. */
  Bytes get(const std::string& name, char dir) const {
    Bytes out;
    for (size_t i = 0; i < frames.size(); ++i) {
      const std::string& n = frames[i].first;
      if (frames[i].second.first != dir) continue;
      if (n == name || (n.compare(0, name.size() + 1, name + "[") == 0)) {
        out.insert(out.end(), frames[i].second.second.begin(), frames[i].second.second.end());
      }
    }
    CHECK(!out.empty(), "no frame %s in the transcript", name.c_str());
    return out;
  }
};

inline void expect_bytes(const char* step, const Bytes& got, const Bytes& want) {
  CHECK(got == want, "%s: the board wrote\n  %s\nbut the transcript has\n  %s", step,
        check::hex(got).c_str(), check::hex(want).c_str());
}

/** A host that writes frames: its own best-effort and reliable numbering. */
struct Host {
  uint8_t be_seq = 0;
  uint8_t rel_seq = 0;
  Bytes frame(hwbridge::FrameType type, uint8_t channel, uint8_t seq, const Bytes& payload,
              hwbridge::Frag frag = hwbridge::Frag::Whole) {
    check::VecSink sink;
    hwbridge::FrameHeader h;
    h.type = type;
    h.frag = frag;
    h.channel = channel;
    h.seq = seq;
    hwbridge::write_frame(sink, h, payload.data(), payload.size());
    return sink.bytes;
  }
  Bytes be(uint8_t channel, const Bytes& payload) {
    return frame(hwbridge::FrameType::BestEffort, channel, be_seq++, payload);
  }
  Bytes rel(uint8_t channel, const Bytes& payload) {
    return frame(hwbridge::FrameType::Reliable, channel, rel_seq++, payload);
  }
  Bytes ack(uint8_t seq) { return frame(hwbridge::FrameType::Ack, 0, seq, Bytes()); }
};

/** Replays the transcript's handshake and table (examples A-G) into a fresh golden board: the
 * board is CONNECTED at t = 10.0 s; the host's next best-effort seq is 2 and reliable seq 3. */
inline void connect(GoldenBoard& b, const Transcript& tr, Host* host) {
  b.start(10.0);
  const char* steps[][2] = {{"hello_host", "hello_device"},
                            {"hello_host_established", "board_info"},
                            {"ack", "topic_entry"},
                            {"topic_ack", "topic_entry_service"},
                            {"topic_ack_service", "table_end"},
                            {"ready", "ack_ready"}};
  for (size_t i = 0; i < sizeof(steps) / sizeof(steps[0]); ++i) {
    expect_bytes(steps[i][1], b.input(tr.get(steps[i][0], 'h'), 10.0), tr.get(steps[i][1], 'd'));
  }
  CHECK(b.node.connected(), "not connected after READY");
  host->be_seq = 2;
  host->rel_seq = 3;
}

inline uint32_t detail_get32(const Bytes& b, size_t at) {
  return static_cast<uint32_t>(b[at] | b[at + 1] << 8 | b[at + 2] << 16) | static_cast<uint32_t>(b[at + 3]) << 24;
}

/** The frames in wire bytes (delimiter-separated runs, leading zeros dropped), decoded. */
inline std::vector<std::pair<hwbridge::Frame, Bytes> > frames_of(const Bytes& wire) {
  std::vector<std::pair<hwbridge::Frame, Bytes> > out;
  hwbridge::FrameDecoder<1024> dec;
  for (size_t i = 0; i < wire.size(); ++i) {
    if (dec.push(wire[i]) == hwbridge::Decoded::Frame) {
      const hwbridge::Frame& f = dec.frame();
      out.push_back(std::make_pair(f, Bytes(f.payload, f.payload + f.size)));
      out.back().first.payload = nullptr;
    }
  }
  return out;
}

/** Brings a board that has begun (session 0xcafef00d) to CONNECTED against a scripted host
 * (session 0x12345678, ISN 0, MTU 1024, window 16, `features`): the HELLO exchange, then every
 * reliable frame ACKed, every TOPIC accepted and READY after TABLE_END. The board's output is
 * taken; `host` keeps its numbering for what the test sends next. */
template <class NodeT>
void connect_scripted(NodeT& node, FakeHardware& hw, Host& host, uint8_t features,
                      uint32_t max_message = 0x100000) {
  Bytes hello{0x01, 1, 0, 0, 0x78, 0x56, 0x34, 0x12, 0, 0, 0, 0, 0, 4, 0, 0, 0, 0, 16, 0, features};
  for (int i = 0; i < 4; ++i) hello[14 + i] = static_cast<uint8_t>(max_message >> (8 * i));
  hw.feed(host.be(0, hello));
  node.processInput();
  hello[3] = 1;  // ESTABLISHED, echoing the board's session
  hello[8] = 0x0d;
  hello[9] = 0xf0;
  hello[10] = 0xfe;
  hello[11] = 0xca;
  hw.feed(host.be(0, hello));
  for (int round = 0; round < 20 && !node.connected(); ++round) {
    node.processInput();
    node.runTimers();
    std::vector<std::pair<hwbridge::Frame, Bytes> > fr = frames_of(hw.take());
    for (size_t i = 0; i < fr.size(); ++i) {
      if (fr[i].first.type != hwbridge::FrameType::Reliable) continue;
      hw.feed(host.ack(fr[i].first.seq));
      const Bytes& m = fr[i].second;
      if (m[0] == 0x11) hw.feed(host.rel(0, Bytes{0x13, m[1], 0}));
      if (m[0] == 0x12) hw.feed(host.rel(0, Bytes{0x14, m[1]}));
    }
  }
  node.processInput();
  hw.take();
}

}  // namespace harness

#endif  // HWBRIDGE_TESTS_SESSION_HARNESS_H
