// The board session (hwbridge/node.h) against the golden transcript of PROTOCOL.md 2.12
// (protocols/vectors/native_session.json, fed on stdin by session_vectors.py): every byte the
// board writes is compared with the transcript. Then the session's own rules: bad input counted
// and dropped with the session kept, heartbeats, the link timeout, restarts of the host,
// GOODBYE, pending requests failing when the session ends. The tests of service calls are in
// session_services.h.
//
//   python3 firmware/tests/session_vectors.py | BUILD/test_session
#include "session_harness.h"
#include "session_services.h"

using harness::Bytes;
using harness::GoldenBoard;
using harness::Host;
using harness::Transcript;
using harness::expect_bytes;
using hwbridge::FrameType;

namespace {

hwbridge::ParamValue g_last;
int g_answers = 0;
int32_t g_value = 0;
std::string g_name;

void on_param(const hwbridge::ParamValue& v) {
  g_last = v;
  g_name.assign(v.name ? v.name : "", v.name_len);
  g_value = v.ok() ? v.asInt() : -1;
  ++g_answers;
}

/** The whole transcript, step by step as build_transcript() in
 * tests/protocols/test_native_session.py runs it. */
void golden(const Transcript& tr) {
  GoldenBoard b;
  Host host;
  harness::connect(b, tr, &host);
  const double t = 10.001;
  expect_bytes("time_request", b.timers(t), tr.get("time_request", 'd'));
  Bytes in = tr.get("time_response", 'h');
  const Bytes req = tr.get("host_time_request", 'h');
  in.insert(in.end(), req.begin(), req.end());
  expect_bytes("host_time_response", b.input(in, t + 0.002), tr.get("host_time_response", 'd'));
  CHECK(b.node.timeSynced(), "no time sync after TIME_RESPONSE");
  uint32_t sec = 0, nsec = 0;
  b.node.now(&sec, &nsec);  // t3 (1700000000.002) + rtt / 2 (1 ms), read at t4
  CHECK(sec == 1700000000UL && nsec == 3000000UL, "host time %u.%09u", sec, nsec);

  const uint8_t hello[] = {5, 0, 0, 0, 'h', 'e', 'l', 'l', 'o'};
  harness::Raw m;
  m.p = hello;
  m.n = sizeof(hello);
  CHECK(b.chatter.publish(m), "publish refused");
  expect_bytes("topic_data", b.hw().take(), tr.get("topic_data", 'd'));
  uint8_t big[70] = {0x28, 0, 0, 0};
  for (int i = 0; i < 40; ++i) big[4 + i] = static_cast<uint8_t>('0' + i % 10);
  for (int i = 44; i < 70; ++i) big[i] = '!';
  m.p = big;
  m.n = sizeof(big);
#ifdef HWBRIDGE_TEST_HELLO
  // the hello-world build holds no message above its MTU: publish() says so, nothing is written
  CHECK(!b.chatter.publish(m), "a 70-byte publish was sent without fragmentation");
  expect_bytes("topic_data_fragments (refused)", b.hw().take(), Bytes());
#else
  CHECK(b.chatter.publish(m), "publish of 70 bytes refused");
  expect_bytes("topic_data_fragments", b.hw().take(), tr.get("topic_data_fragments", 'd'));
#endif

  expect_bytes("service_response", b.input(tr.get("service_request", 'h'), t + 0.005),
               tr.get("service_response", 'd'));
  expect_bytes("ack_service_response", b.input(tr.get("ack_service_response", 'h'), t + 0.006), Bytes());

  const uint16_t id = b.node.requestParam("rate", hwbridge::kParamInt32, &on_param, true);
  CHECK(id == 1, "request id %u", id);
  expect_bytes("param_get", b.hw().take(), tr.get("param_get", 'd'));
  expect_bytes("ack_param_value", b.input(tr.get("param_value", 'h'), t + 0.008), tr.get("ack_param_value", 'd'));
  CHECK(g_answers == 1 && g_value == 50 && g_name == "rate" && g_last.request_id == 1, "rate: %d", g_value);
  CHECK(g_last.type == hwbridge::kParamInt32 && g_last.count() == 1, "type %u", g_last.type);

  CHECK(b.node.requestParam("missing", hwbridge::kParamAny, &on_param) == 2, "second request id");
  expect_bytes("param_get_missing", b.hw().take(), tr.get("param_get_missing", 'd'));
  expect_bytes("ack_param_not_found", b.input(tr.get("param_not_found", 'h'), t + 0.010),
               tr.get("ack_param_not_found", 'd'));
  CHECK(g_answers == 2 && g_last.status == hwbridge::kParamNotFound && g_name == "missing", "not found");

  expect_bytes("ack_param_push", b.input(tr.get("param_push", 'h'), t + 0.011), tr.get("ack_param_push", 'd'));
  CHECK(g_answers == 3 && g_last.request_id == 0 && g_value == 100, "push: %d", g_value);

  CHECK(b.node.logWarn("low battery"), "log refused");
  expect_bytes("log", b.hw().take(), tr.get("log", 'd'));
  expect_bytes("ack_log", b.input(tr.get("ack_log", 'h'), t + 0.012), Bytes());
  expect_bytes("heartbeat_host", b.input(tr.get("heartbeat_host", 'h'), t + 0.2), Bytes());
  CHECK(b.node.connected(), "a heartbeat ended the session");
  expect_bytes("goodbye", b.input(tr.get("goodbye", 'h'), t + 0.2), Bytes());
  CHECK(!b.node.connected() && b.node.stats().peer_resets == 1, "GOODBYE did not end the session");
  // a new handshake: a HELLO at once, without ESTABLISHED, knowing no host
  const Bytes again = b.timers(t + 0.21);
  std::vector<std::pair<hwbridge::Frame, Bytes> > fr = harness::frames_of(again);
  CHECK(fr.size() == 1 && fr[0].second.size() == 21 && fr[0].second[0] == 0x01 && fr[0].second[3] == 0 &&
            harness::detail_get32(fr[0].second, 8) == 0,
        "after GOODBYE: %s", check::hex(again).c_str());
  const hwbridge::NodeStats& s = b.node.stats();
  CHECK(s.sessions == 1 && s.protocol_errors == 0 && s.dropped_messages == 0 && s.tx_refused == 0,
        "counters: sessions %u errors %u dropped %u refused %u", s.sessions, s.protocol_errors,
        s.dropped_messages, s.tx_refused);
  // %lu, not %zu: newlib-nano's printf (the ARM replay in QEMU) has no z modifier
  printf("golden transcript: %lu frames, every byte as PROTOCOL.md 2.12\n",
         static_cast<unsigned long>(tr.golden));
}

/** Bad input on a connected board: counted, dropped, the session kept, no write past a buffer
 * (ASan watches). */
void bad_input(const Transcript& tr) {
  GoldenBoard b;
  Host host;
  harness::connect(b, tr, &host);
  double t = 10.01;
  // a wrong CRC
  Bytes f = host.rel(0, Bytes{0x40, 1, 'x'});
  f[3] ^= 0x10;
  b.input(f, t);
  host.rel_seq--;  // never received: the next frame reuses the seq
  // an oversize run, and a frame above the MTU
  Bytes junk(300, 0x41);
  junk.push_back(0);
  b.input(junk, t);
  b.input(host.frame(FrameType::BestEffort, 1, host.be_seq++, Bytes(100, 1)), t);
  CHECK(b.node.connected(), "bad frames ended the session");
  // an unknown opcode, a short message, a wrong-stream opcode: protocol errors, ACKed
  const hwbridge::Counter errors0 = b.node.stats().protocol_errors;
  Bytes out = b.input(host.rel(0, Bytes{0x7f, 1, 2}), t);
  CHECK(!out.empty(), "no ACK for an unknown opcode");
  b.input(host.rel(0, Bytes{0x21, 2}), t);        // SERVICE_RESPONSE too short
  b.input(host.rel(0, Bytes{0x02}), t);           // HEARTBEAT on the reliable stream
  b.input(host.be(0, Bytes{0x14, 1}), t);         // READY on the best-effort stream
  b.input(host.rel(0, Bytes{0x11, 1, 2, 3}), t);  // TOPIC: only a board sends it
  b.input(host.rel(0, Bytes{0x40, 9, 'x'}), t);   // LOG level 9
  b.input(host.rel(0, Bytes{0x31, 5, 0, 0, 200, 'a'}), t);  // PARAM_VALUE name past the end
  CHECK(b.node.stats().protocol_errors == errors0 + 7, "protocol errors %u", b.node.stats().protocol_errors);
  // data on an unknown channel, on a publisher's channel: dropped
  b.input(host.be(9, Bytes{1, 2, 3}), t);
  b.input(host.be(1, Bytes{1, 2, 3}), t);
  CHECK(b.node.stats().dropped_messages == 2, "dropped %u", b.node.stats().dropped_messages);
  // a fragmented message above max_message (64): refused by reassembly, nothing kept
  Bytes first{0x00, 0x04, 0, 0};
  first.resize(64, 7);
  b.input(host.frame(FrameType::Reliable, 0, host.rel_seq++, first, hwbridge::Frag::First), t);
  b.input(host.frame(FrameType::Reliable, 0, host.rel_seq++, Bytes(64, 8), hwbridge::Frag::Middle), t);
  // a service request for a channel that is not a server: NO_SERVICE; a request that does not
  // deserialize: ERROR with a reason
  out = b.input(host.rel(0, Bytes{0x20, 1, 9, 0}), t);
  std::vector<std::pair<hwbridge::Frame, Bytes> > fr = harness::frames_of(out);
  CHECK(fr.size() == 2 && fr[1].second == (Bytes{0x21, 1, 9, 0, 2}), "NO_SERVICE: %s", check::hex(out).c_str());
  b.input(host.ack(fr[1].first.seq), t);
  out = b.input(host.rel(0, Bytes{0x20, 2, 10, 0, 1, 2}), t);
  fr = harness::frames_of(out);
  CHECK(fr.size() == 2 && fr[1].second.size() > 5 && fr[1].second[4] == 1, "ERROR: %s", check::hex(out).c_str());
  b.input(host.ack(fr[1].first.seq), t);
  // the session still works: a service call is answered
  out = b.input(host.rel(0, Bytes{0x20, 2, 11, 0}), t);
  fr = harness::frames_of(out);
  CHECK(fr.size() == 2 && fr[1].second == (Bytes{0x21, 2, 11, 0, 0, 1, 2, 0, 0, 0, 'o', 'k'}),
        "service after bad input: %s", check::hex(out).c_str());
  CHECK(b.node.connected() && b.node.stats().sessions == 1, "the session did not survive");
  printf("bad input: counted and dropped, session kept\n");
}

/** Heartbeats after 100 ms without sending; the link timeout after 800 ms without a frame. */
void liveness(const Transcript& tr) {
  GoldenBoard b;
  Host host;
  harness::connect(b, tr, &host);
  Bytes out = b.timers(10.05);
  std::vector<std::pair<hwbridge::Frame, Bytes> > fr = harness::frames_of(out);
  CHECK(fr.size() == 1 && fr[0].second[0] == 0x03, "time request expected first: %s", check::hex(out).c_str());
  out = b.timers(10.16);
  fr = harness::frames_of(out);
  CHECK(fr.size() == 1 && fr[0].second == Bytes{0x02} && out[0] == 0, "heartbeat (led by 0x00): %s",
        check::hex(out).c_str());
  b.input(host.be(0, Bytes{0x02}), 10.5);
  CHECK(b.node.connected(), "not connected");
  b.timers(11.29);
  CHECK(b.node.connected(), "link lost too early");
  out = b.timers(11.31);
  CHECK(!b.node.connected() && b.node.stats().link_losses == 1, "no link loss after 0.8 s");
  fr = harness::frames_of(out);
  CHECK(fr.size() == 1 && fr[0].second[0] == 0x01, "a HELLO at once after the link loss: %s", check::hex(out).c_str());
  // the backoff: 50, 100, 200, then every 250 ms (the board's timers count ticks of 1.024 ms:
  // each wait within 2 ms), the timers run every millisecond
  const double waits[] = {0.050, 0.100, 0.200, 0.250, 0.250};
  double last = 11.31;
  size_t i = 0;
  for (int ms = 1; ms <= 1000 && i < 5; ++ms) {
    const double t = 11.31 + ms * 0.001;
    if (b.timers(t).empty()) continue;
    CHECK(t - last > waits[i] - 0.0025 && t - last < waits[i] + 0.0025, "HELLO %zu after %.4f s, not %.3f",
          i, t - last, waits[i]);
    last = t;
    ++i;
  }
  CHECK(i == 5, "%zu HELLOs in a second", i);
  printf("liveness: heartbeat, link timeout, HELLO backoff\n");
}

/** A host restart (HELLO with another session id) ends the session; pending requests fail. */
void restarts(const Transcript& tr) {
  GoldenBoard b;
  Host host;
  harness::connect(b, tr, &host);
  g_answers = 0;
  CHECK(b.node.requestParam("kp", hwbridge::kParamFloat32, &on_param) != 0, "request refused");
  b.hw().take();
  // the host restarted: a HELLO from session 0x11111111 knowing no board
  Bytes hello{0x01, 1, 0, 0, 0x11, 0x11, 0x11, 0x11, 0, 0, 0, 0, 0, 4, 0, 0, 0x10, 0, 16, 5, 7};
  Bytes out = b.input(host.be(0, hello), 10.1);
  CHECK(!b.node.connected() && b.node.stats().peer_resets == 1, "host restart not detected");
  CHECK(g_answers == 1 && g_last.status == hwbridge::kParamSessionReset, "pending request: %d", g_answers);
  std::vector<std::pair<hwbridge::Frame, Bytes> > fr = harness::frames_of(out);
  CHECK(fr.size() == 1 && fr[0].second[0] == 0x01 && harness::detail_get32(fr[0].second, 8) == 0x11111111UL,
        "answer to the new host: %s", check::hex(out).c_str());
  // blocking calls fail cleanly too: the link is lost while getParam spins
  GoldenBoard c;
  Host h2;
  harness::connect(c, tr, &h2);
  c.hw().step_us = 1000;
  int32_t v = 7;
  CHECK(!c.node.getParam("rate", &v), "getParam without a host succeeded");
  CHECK(v == 7 && c.node.stats().link_losses == 1, "getParam: v %d losses %u", v, c.node.stats().link_losses);
  printf("restarts: host restart detected, pending requests fail\n");
}

/** A board with window 2 (ComfortableProfile) holds a frame that arrives early: it is delivered
 * after the missing one, in order, and the ACK's bitmap shows it held meanwhile (2.4). */
std::vector<std::string> g_cmds;
void on_cmd(const std_msgs::String& m) { g_cmds.push_back(m.data.c_str()); }

struct WindowBoard {
  hwbridge::NodeHandle_<harness::FakeHardware, hwbridge::ComfortableProfile> node;
  hwbridge::Subscriber<std_msgs::String> cmd{"/cmd", &on_cmd, true};
  WindowBoard() : node() {}
};

Bytes string_msg(const char* s) {
  std_msgs::String m;
  m.data = s;
  uint8_t buf[40];
  const size_t n = m.serialize(buf, sizeof(buf));
  return Bytes(buf, buf + n);
}

void early_frames() {
  WindowBoard b;
  harness::FakeHardware& hw = b.node.getHardware();
  b.node.setIdentity(0xcafef00dUL, 0);
  b.node.subscribe(b.cmd);
  hw.clock = 1000000;
  b.node.begin("window", "");
  Host host;
  harness::connect_scripted(b.node, hw, host, 3);
  CHECK(b.node.connected() && b.cmd.accepted(), "window board not connected");
  const uint8_t first = host.rel_seq;
  const Bytes one = host.rel(1, string_msg("one"));
  const Bytes two = host.rel(1, string_msg("two"));
  // the second arrives first: held, not delivered; the ACK names first - 1 and the held frame
  hw.feed(two);
  b.node.processInput();
  std::vector<std::pair<hwbridge::Frame, Bytes> > fr = harness::frames_of(hw.take());
  CHECK(g_cmds.empty(), "an early frame was delivered before the missing one");
  CHECK(fr.size() == 1 && fr[0].first.type == FrameType::Ack &&
            fr[0].first.seq == static_cast<uint8_t>(first - 1) && fr[0].second == Bytes{0x01},
        "ACK with the early frame held: %zu frames", fr.size());
  // the missing one: both delivered in order, one cumulative ACK
  hw.feed(one);
  b.node.processInput();
  fr = harness::frames_of(hw.take());
  CHECK(g_cmds.size() == 2 && g_cmds[0] == "one" && g_cmds[1] == "two", "delivered %zu", g_cmds.size());
  CHECK(fr.size() == 1 && fr[0].first.type == FrameType::Ack &&
            fr[0].first.seq == static_cast<uint8_t>(first + 1) && fr[0].second.empty(),
        "cumulative ACK after the gap closed");
  printf("early frames: a window-2 board holds the early frame and delivers both in order\n");
}
/** txReady(): false before the session, true while the window has room, false once a reliable
 * message waits for a slot (the next publish would spin), true again after the host's ACK. */
struct ReliableWindowBoard {
  hwbridge::NodeHandle_<harness::FakeHardware, hwbridge::ComfortableProfile> node;
  hwbridge::Publisher<std_msgs::String> out{"/out", true};
  ReliableWindowBoard() : node() {}
};

void tx_ready() {
  ReliableWindowBoard b;
  harness::FakeHardware& hw = b.node.getHardware();
  b.node.setIdentity(0xcafef00dUL, 0);
  b.node.advertise(b.out);
  hw.clock = 1000000;
  b.node.begin("ready", "");
  CHECK(!b.node.txReady(), "txReady before a session");
  Host host;
  harness::connect_scripted(b.node, hw, host, 3);
  CHECK(b.node.connected() && b.out.accepted(), "board not connected");
  std_msgs::String m;
  m.data = "x";
  std::vector<uint8_t> seqs;
  // window 2: two frames go out unacknowledged; the third waits for a slot
  for (int i = 0; i < 3; ++i) {
    CHECK(b.node.txReady(), "txReady false before publish %d", i);
    CHECK(b.out.publish(m), "publish %d refused", i);
    std::vector<std::pair<hwbridge::Frame, Bytes> > fr = harness::frames_of(hw.take());
    for (size_t k = 0; k < fr.size(); ++k) {
      if (fr[k].first.type == FrameType::Reliable) seqs.push_back(fr[k].first.seq);
    }
  }
  CHECK(seqs.size() == 2, "%zu reliable frames sent with a window of 2", seqs.size());
  CHECK(!b.node.txReady(), "txReady with a message waiting for a window slot");
  hw.feed(host.ack(seqs[0]));
  b.node.processInput();
  CHECK(b.node.txReady(), "txReady false after the ACK freed a slot");
  printf("txReady: false while a reliable message waits for a window slot, true after the ACK\n");
}

/** A host MTU below what the board sends whole: a board that never fragments (kTxBuffer within
 * its MTU) refuses the host as invalid limits, counted; one that fragments establishes. */
void small_mtu_host() {
  harness::Node node;
  harness::FakeHardware& hw = node.getHardware();
  node.setIdentity(0xcafef00dUL, 0);
  hw.clock = 1000000;
  node.begin("mtu", "");
  Host host;
  // session 0x12345678 already echoing the board, MTU 32
  Bytes hello{0x01, 1, 0, 0, 0x78, 0x56, 0x34, 0x12, 0x0d, 0xf0, 0xfe, 0xca, 32, 0, 0, 0, 0x10, 0, 16, 0, 3};
  hw.feed(host.be(0, hello));
  node.processInput();
  const bool fragments = harness::GoldenProfile::kTxBuffer > harness::GoldenProfile::kMtu;
  CHECK(node.stats().sessions == (fragments ? 1 : 0) && node.stats().protocol_errors == (fragments ? 0 : 1),
        "MTU 32: sessions %u, errors %u", node.stats().sessions, node.stats().protocol_errors);
  printf("small host MTU: %s\n", fragments ? "established (the board fragments)" : "refused (no fragmentation)");
}

/** A board whose session host can be scripted step by step: a reliable publisher, connected. */
template <class P>
struct StepBoardOf {
  hwbridge::NodeHandle_<harness::FakeHardware, P> node;
  hwbridge::Publisher<harness::Raw> rel{"/rel", true};
  hwbridge::ServiceServer<std_srvs::Trigger> reset{"/reset", &harness::on_reset};  // channel 2
  Host host;
  explicit StepBoardOf(uint32_t max_message = 0x100000) : node() {
    harness::FakeHardware& hw = node.getHardware();
    node.setIdentity(0xcafef00dUL, 0);
    node.advertise(rel);
    node.advertiseService(reset);
    hw.clock = 10000000;
    node.begin("step", "");
    harness::connect_scripted(node, hw, host, P::kFeatures, max_message);
    CHECK(node.connected(), "step board not connected");
  }
  harness::FakeHardware& hw() { return node.getHardware(); }
  /** ms of time in 50 ms steps, the host sending a heartbeat at each, spinOnce after it. */
  void spin_ms(uint32_t ms) {
    for (uint32_t t = 0; t < ms; t += 50) {
      hw().clock += 50000;
      hw().feed(host.be(0, Bytes{0x02}));
      node.spinOnce();
    }
  }
};
typedef StepBoardOf<harness::GoldenProfile> StepBoard;

int reliable_frames(const Bytes& out) {
  int n = 0;
  std::vector<std::pair<hwbridge::Frame, Bytes> > fr = harness::frames_of(out);
  for (size_t i = 0; i < fr.size(); ++i) n += fr[i].first.type == FrameType::Reliable;
  return n;
}

/** A service request that arrives while the board's transmit buffer holds a message waiting
 * for the reliable window (window 1: a frame in flight, the next message behind it) has no room
 * for its answer: the board takes it back unacknowledged (the ACK it writes covers only the
 * frames before it) and answers it when the host sends it again, once the window moved on. It
 * is never acknowledged and then dropped (the host would learn only at its call timeout). */
template <class P>
void busy_tx_request() {
  StepBoardOf<P> b;
  hwbridge::NodeHandle_<harness::FakeHardware, P>& node = b.node;
  harness::FakeHardware& hw = b.hw();
  Host& host = b.host;
  const uint8_t text[] = {1, 0, 0, 0, 'a'};
  harness::Raw m;
  m.p = text;
  m.n = sizeof(text);
  CHECK(b.rel.publish(m), "first reliable publish refused");
  std::vector<std::pair<hwbridge::Frame, Bytes> > fr = harness::frames_of(hw.take());
  CHECK(fr.size() == 1 && fr[0].first.type == FrameType::Reliable, "first publish: %zu frames", fr.size());
  const uint8_t first = fr[0].first.seq;
  CHECK(b.rel.publish(m), "second reliable publish refused (it waits behind the first)");
  CHECK(hw.take().empty() && !node.txReady(), "the second message did not wait for the window");

  const uint8_t req_seq = host.rel_seq;
  const std::pair<uint8_t, Bytes> call = call_message<P>(0x20, 2, Bytes{7, 0});  // /reset, id 7
  const Bytes request = host.rel(call.first, call.second);
  const std::pair<uint8_t, Bytes> reply = call_message<P>(0x21, 2, Bytes{7, 0, 0, 1, 2, 0, 0, 0, 'o', 'k'});
  const hwbridge::Counter refused = node.stats().tx_refused;
  hw.feed(request);
  node.spinOnce();
  fr = harness::frames_of(hw.take());
  for (size_t i = 0; i < fr.size(); ++i) {
    CHECK(fr[i].first.type != FrameType::Reliable, "the board sent a reliable frame with its window full");
    CHECK(fr[i].first.type != FrameType::Ack || fr[i].first.seq != req_seq,
          "the board acknowledged a request it had no room to answer");
  }
  CHECK(node.stats().tx_refused == refused, "the request was counted as refused: %u", node.stats().tx_refused);

  // the host acknowledges the first message: the second goes out, then is acknowledged
  hw.feed(host.ack(first));
  node.spinOnce();
  fr = harness::frames_of(hw.take());
  CHECK(fr.size() == 1 && fr[0].first.type == FrameType::Reliable && fr[0].second == Bytes(text, text + 5),
        "the waiting message did not follow the ACK");
  hw.feed(host.ack(fr[0].first.seq));
  node.spinOnce();
  hw.take();
  // until the request comes again, the buffer is its answer's: a sketch publishing whenever a slot
  // frees (the soak bench's boards) would otherwise refill it before every retransmission, the
  // request would never be answered and the host's retry limit would end the session
  CHECK(!b.rel.publish(m), "a reliable publish took the buffer a taken-back request waits for");
  hw.take();

  // the host's retransmission (same frame, same seq) is answered
  hw.clock += 300000;
  hw.feed(request);
  node.spinOnce();
  fr = harness::frames_of(hw.take());
  bool acked = false;
  bool answered = false;
  uint8_t answer_seq = 0;
  for (size_t i = 0; i < fr.size(); ++i) {
    acked = acked || (fr[i].first.type == FrameType::Ack && fr[i].first.seq == req_seq);
    if (fr[i].first.type == FrameType::Reliable && fr[i].first.channel == reply.first &&
        fr[i].second == reply.second) {
      answered = true;
      answer_seq = fr[i].first.seq;
    }
  }
  CHECK(acked && answered, "the repeated request was not acknowledged and answered: %zu frames", fr.size());
  CHECK(node.connected() && node.stats().tx_refused == refused + 1, "session lost or request refused");
  hw.feed(host.ack(answer_seq));
  node.spinOnce();
  hw.take();
  CHECK(b.rel.publish(m), "reliable publishing did not resume once the request was answered");
  printf("busy transmit buffer%s: a service request is taken back unacknowledged, keeps the buffer for its "
         "answer, and is answered when repeated\n", call_form<P>());
}

/** Time sync (2.8): of its last 4 answers the board follows the newest whose round trip is
 * within 25 % (or 0.1 ms) of the shortest kept; a new session forgets them. */
void time_samples() {
  StepBoard b;
  harness::Node& node = b.node;
  harness::FakeHardware& hw = b.hw();
  Host& host = b.host;
  CHECK(node.timeSamples() == 0, "time samples before any answer");
  // (round trip in µs, the host's second in its answer, the sample expected in use after it)
  const struct {
    uint32_t rtt;
    uint32_t sec;
    int use;
  } steps[] = {{10000, 1000, 0}, {2000, 2000, 1},  {2400, 3000, 2}, {8000, 4000, 2},
               {9000, 5000, 2},  {9000, 6000, 2},  {9000, 7000, 6}, {50, 8000, 7},
               {140, 9000, 8},   {200, 10000, 8}};
  const uint32_t busy = 500;  // the host's time between t2 and t3
  for (int k = 0; k < 10; ++k) {
    const uint32_t t4 = 20000000UL + static_cast<uint32_t>(k) * 1000000UL;
    hw.clock = t4;
    Bytes r{0x04};
    const uint32_t fields[] = {t4 - steps[k].rtt - busy, steps[k].sec, 0, steps[k].sec, busy * 1000};
    for (size_t f = 0; f < 5; ++f) {
      for (int i = 0; i < 4; ++i) r.push_back(static_cast<uint8_t>(fields[f] >> (8 * i)));
    }
    hw.feed(host.be(0, r));
    node.processInput();
    hw.take();
    const int u = steps[k].use;
    uint32_t sec = 0, nsec = 0;
    node.now(&sec, &nsec);  // the sample in use, carried forward by the board's clock
    const uint32_t want_sec = steps[u].sec + static_cast<uint32_t>(k - u);
    const uint32_t want_nsec = busy * 1000 + steps[u].rtt / 2 * 1000;
    CHECK(sec == want_sec && nsec == want_nsec, "answer %d: host time %u.%09u, expected %u.%09u (sample %d)", k,
          sec, nsec, want_sec, want_nsec, u);
    CHECK(node.timeSamples() == (k < 4 ? k + 1 : 4), "answer %d: %u samples kept", k, node.timeSamples());
  }
  // 40 s without a timer run (beyond the 16-bit ticks' signed range): the request due long ago
  // goes out at the next run
  hw.take();
  hw.clock += 40000000UL;
  hw.feed(host.be(0, Bytes{0x02}));
  node.spinOnce();
  bool asked = false;
  const std::vector<std::pair<hwbridge::Frame, Bytes> > out = harness::frames_of(hw.take());
  for (size_t i = 0; i < out.size(); ++i) asked = asked || out[i].second[0] == 0x03;
  CHECK(asked && node.connected(), "no TIME_REQUEST after a 40 s pause");
  hw.feed(host.be(0, Bytes{0x05}));  // GOODBYE: the session ends, its samples with it
  node.processInput();
  CHECK(!node.connected() && !node.timeSynced() && node.timeSamples() == 0, "samples after GOODBYE: %u",
        node.timeSamples());
  printf("time samples: the newest of the shortest round trips of the last 4, forgotten with the session\n");
}

std::vector<std::pair<int, uint8_t> > g_param_calls;  // (callback, status)
void param_cb1(const hwbridge::ParamValue& v) { g_param_calls.push_back(std::make_pair(1, v.status)); }
void param_cb2(const hwbridge::ParamValue& v) { g_param_calls.push_back(std::make_pair(2, v.status)); }

/** Sends take the time when they are made, not at the last spinOnce: a reliable message
 * published after 300 ms of sketch work is not resent 2 ms later, and a parameter request made
 * 700 ms after the last spin times out 2 s after it was made. */
void send_times() {
  StepBoard b;
  b.node.spinOnce();
  b.hw().take();
  b.hw().clock += 300000;
  const uint8_t d[] = {1, 0, 0, 0, 'x'};
  harness::Raw m;
  m.p = d;
  m.n = sizeof(d);
  CHECK(b.rel.publish(m), "reliable publish");
  const Bytes sent = b.hw().take();
  CHECK(reliable_frames(sent) == 1, "one reliable frame");
  b.hw().clock += 2000;
  b.hw().feed(b.host.be(0, Bytes{0x02}));
  b.node.spinOnce();
  CHECK(reliable_frames(b.hw().take()) == 0, "resent 2 ms after it was sent");
  b.hw().feed(b.host.ack(harness::frames_of(sent).back().first.seq));
  b.spin_ms(100);
  b.hw().take();

  b.hw().clock += 700000;  // sketch work, then the request
  g_param_calls.clear();
  const uint16_t id = b.node.requestParam("a", hwbridge::kParamInt32, &param_cb1);
  CHECK(id != 0, "request refused");
  b.hw().feed(b.host.ack(harness::frames_of(b.hw().take()).back().first.seq));
  b.spin_ms(1900);
  CHECK(g_param_calls.empty(), "timed out within 1.9 s of the request");
  b.spin_ms(200);
  CHECK(g_param_calls.size() == 1 && g_param_calls[0].second == hwbridge::kParamTimeout, "no timeout");

  // a second request while one is pending is refused, and the first keeps its callback
  g_param_calls.clear();
  const uint16_t first = b.node.requestParam("a", hwbridge::kParamInt32, &param_cb1);
  const Bytes asked = b.hw().take();
  CHECK(first != 0 && b.node.requestParam("b", hwbridge::kParamInt32, &param_cb2) == 0, "refused");
  b.hw().feed(b.host.ack(harness::frames_of(asked).back().first.seq));
  b.hw().feed(b.host.rel(0, Bytes{0x31, static_cast<uint8_t>(first), static_cast<uint8_t>(first >> 8), 0, 1, 'a',
                                  2, 7, 0, 0, 0}));
  b.spin_ms(50);
  CHECK(g_param_calls.size() == 2 && g_param_calls[0] == std::make_pair(2, uint8_t(hwbridge::kParamNotConnected)) &&
            g_param_calls[1] == std::make_pair(1, uint8_t(hwbridge::kParamOk)),
        "callbacks: %zu", g_param_calls.size());
  printf("send times: publish and parameter requests take the time they are made; a refused request keeps the pending one's callback\n");
}

/** A host whose max_message is below what a log or a service answer needs: both refused, never a
 * write past the transmit buffer (the sanitizer build checks). The host's HELLOs alone keep the
 * session alive (2.9). */
void small_hosts_and_hellos() {
  StepBoard b(1);
  static char text[200];
  memset(text, 'A', sizeof(text) - 1);
  const hwbridge::Counter refused = b.node.stats().tx_refused;
  CHECK(!b.node.logInfo(text) && b.node.stats().tx_refused == refused + 1, "log to a max_message 1 host");
  b.hw().feed(b.host.rel(0, Bytes{0x20, 2, 9, 0}));  // a call of /reset: no answer fits
  b.node.spinOnce();
  const std::vector<std::pair<hwbridge::Frame, Bytes> > out = harness::frames_of(b.hw().take());
  for (size_t i = 0; i < out.size(); ++i) {
    CHECK(out[i].first.type != FrameType::Reliable, "an answer above the host's max_message");
  }
  CHECK(b.node.stats().tx_refused == refused + 2, "the unanswerable call not counted");

  StepBoard h;
  Bytes hello{0x01, 1, 0, 1, 0x78, 0x56, 0x34, 0x12, 0x0d, 0xf0, 0xfe, 0xca, 0, 4, 0, 0, 0x10, 0, 16, 0, 3};
  for (int i = 0; i < 8; ++i) {  // 1.6 s of ESTABLISHED HELLOs, 200 ms apart, and nothing else
    h.hw().clock += 200000;
    h.hw().feed(h.host.be(0, hello));
    h.node.spinOnce();
  }
  CHECK(h.node.connected() && h.node.stats().link_losses == 0, "HELLOs did not keep the link");
  printf("small hosts: a log that cannot fit is refused; HELLOs are a sign of life\n");
}

/** A long setup() between begin() and the first spinOnce (40 s: beyond the 16-bit ticks'
 * signed range) does not hold back the first HELLO. */
void late_first_spin() {
  harness::Node node;
  harness::FakeHardware& hw = node.getHardware();
  hw.clock = 1000000;
  node.begin("late", "");
  hw.clock += 40000000;
  node.spinOnce();
  const std::vector<std::pair<hwbridge::Frame, Bytes> > fr = harness::frames_of(hw.take());
  CHECK(fr.size() == 1 && fr[0].second[0] == 0x01, "no HELLO at the first spinOnce after 40 s");
  printf("late first spin: the HELLO goes out at once\n");
}

/** A time answer whose round trip is above 8.59 s (answers up to 10 s old count): host time
 * t3 + rtt / 2 without overflowing the nanoseconds. */
void long_round_trip() {
  StepBoard b;
  const uint32_t t4 = b.hw().clock;
  const uint32_t rtt = 9500000;  // 9.5 s
  Bytes r{0x04};
  const uint32_t fields[] = {t4 - rtt, 5000, 0, 5000, 0};
  for (size_t f = 0; f < 5; ++f) {
    for (int i = 0; i < 4; ++i) r.push_back(static_cast<uint8_t>(fields[f] >> (8 * i)));
  }
  b.hw().feed(b.host.be(0, r));
  b.node.processInput();
  uint32_t sec = 0, nsec = 0;
  b.node.now(&sec, &nsec);
  CHECK(sec == 5004 && nsec == 750000000UL, "host time %u.%09u, expected 5004.750000000", sec, nsec);
  printf("long round trip: t3 + 4.75 s\n");
}
}  // namespace

#ifdef HWBRIDGE_EMBEDDED_TRANSCRIPT
// ARM builds run in QEMU (tests/arm/test_session_arm.py): no stdin reaches the board, so the
// transcript's text is compiled in (a generated C file defines it) and read as a file.
extern "C" const char hwbridge_transcript[];
#endif

int main() {
  Transcript tr;
#ifdef HWBRIDGE_EMBEDDED_TRANSCRIPT
  FILE* in = fmemopen(const_cast<char*>(hwbridge_transcript), strlen(hwbridge_transcript), "r");
  CHECK(in != nullptr, "fmemopen failed");
  tr.read(in);
  fclose(in);
#else
  tr.read(stdin);
#endif
  golden(tr);
  bad_input(tr);
  liveness(tr);
  restarts(tr);
  service_client<harness::GoldenProfile>();
  service_client<OwnChannelProfile>();
  service_client<ShortCallsProfile>();
  early_frames();
  tx_ready();
  busy_tx_request<harness::GoldenProfile>();
  busy_tx_request<OwnChannelProfile>();
  busy_tx_request<ShortCallsProfile>();
  small_mtu_host();
  time_samples();
  send_times();
  small_hosts_and_hellos();
  late_first_spin();
  long_round_trip();
  ack_in_data();
  service_channels(tr);
  short_call_heads(tr);
  printf("test_session: %lu checks passed\n", check::count());
  return 0;
}
