// Part of test_session.cpp (included once, after its using-declarations): the tests of service
// calls. A board's service client, ACKs carried in service exchanges (ACK_IN_DATA) and calls on
// the services' own channels (SERVICE_CHANNELS, and SHORT_CALLS), in every form; the golden
// vectors of PROTOCOL.md 2.12 P, Q and R replayed byte for byte.
#ifndef HWBRIDGE_TESTS_SESSION_SERVICES_H
#define HWBRIDGE_TESTS_SESSION_SERVICES_H

#include "session_harness.h"

namespace {

using harness::Bytes;
using harness::Host;
using harness::Transcript;
using harness::expect_bytes;
using hwbridge::FrameType;

/** The golden profile with SERVICE_CHANNELS (PROTOCOL.md 2.8): calls on the services' own
 * channels when the host has it too. */
struct OwnChannelProfile : harness::GoldenProfile {
  static const uint8_t kFeatures = 3 | hwbridge::control::Features::SERVICE_CHANNELS;
};

/** The golden profile with SERVICE_CHANNELS and SHORT_CALLS (PROTOCOL.md 2.8): one-byte heads
 * when the host has both too. */
struct ShortCallsProfile : harness::GoldenProfile {
  static const uint8_t kFeatures =
      3 | hwbridge::control::Features::SERVICE_CHANNELS | hwbridge::control::Features::SHORT_CALLS;
};

/** Whether a board of profile P and a host that announces P's features speak SERVICE_CHANNELS. */
template <class P>
bool own_channels() {
  return (P::kFeatures & hwbridge::control::Features::SERVICE_CHANNELS) != 0;
}

/** Whether they speak SHORT_CALLS too. */
template <class P>
bool short_calls() {
  return own_channels<P>() && (P::kFeatures & hwbridge::control::Features::SHORT_CALLS) != 0;
}

/** The form P's calls take, for the tests' lines. */
template <class P>
const char* call_form() {
  return short_calls<P>() ? " (SHORT_CALLS)" : own_channels<P>() ? " (SERVICE_CHANNELS)" : "";
}

/** A service message as P's session sends it, from its fields as on a service's channel
 * (request id u16, [status u8,] body): there with SERVICE_CHANNELS, with the one-byte head of
 * SHORT_CALLS (the id's low byte; bit 7 and the status when it is not OK) too, else as the
 * control message op on channel 0. */
template <class P>
std::pair<uint8_t, Bytes> call_message(uint8_t op, uint8_t channel, const Bytes& fields) {
  if (short_calls<P>()) {
    Bytes m{fields[0]};
    size_t from = 2;
    if (op == 0x21) {
      from = 3;
      if (fields[2] != 0) {
        m[0] = static_cast<uint8_t>(m[0] | 0x80);
        m.push_back(fields[2]);
      }
    }
    m.insert(m.end(), fields.begin() + static_cast<std::ptrdiff_t>(from), fields.end());
    return std::make_pair(channel, m);
  }
  if (own_channels<P>()) return std::make_pair(channel, fields);
  Bytes m{op, channel};
  m.insert(m.end(), fields.begin(), fields.end());
  return std::make_pair(static_cast<uint8_t>(0), m);
}

/** A board with a service client: calls answered, refused (NO_SERVICE), timed out. The host's
 * answers are queued before the call: request ids and sequence numbers are deterministic. */
template <class P = harness::GoldenProfile>
struct ClientBoard {
  hwbridge::NodeHandle_<harness::FakeHardware, P> node;
  hwbridge::ServiceClient<std_srvs::Trigger> client{"/host_reset"};
  hwbridge::Publisher<harness::Raw> chatter{"/chatter", true};
  ClientBoard() : node() {}
};

/** Host features with HOST_LOG (4) and P's: P's own set is negotiated. */
template <class P>
uint8_t host_features() {
  return static_cast<uint8_t>(P::kFeatures | 4);
}

template <class P>
void service_client() {
  ClientBoard<P> b;
  harness::FakeHardware& hw = b.node.getHardware();
  b.node.setIdentity(0xcafef00dUL, 0);
  b.node.serviceClient(b.client);
  b.node.advertise(b.chatter);
  hw.clock = 1000000;
  b.node.begin("client", "");
  Host host;
  harness::connect_scripted(b.node, hw, host, host_features<P>());
  CHECK(b.node.connected() && b.client.accepted() && b.chatter.accepted(), "client board not connected");
  uint8_t next_seq = 4;  // BOARD_INFO, 2 TOPICs, TABLE_END
  std_srvs::TriggerRequest req;
  std_srvs::TriggerResponse res;
  // a response of the host, on channel 0 or the client's own (1)
  auto answer = [&host](const Bytes& fields) -> Bytes {
    const std::pair<uint8_t, Bytes> m = call_message<P>(0x21, 1, fields);
    return host.rel(m.first, m.second);
  };
  // answered: the host ACKs the request and answers OK
  hw.feed(host.ack(next_seq++));
  hw.feed(answer(Bytes{1, 0, 0, 1, 3, 0, 0, 0, 'y', 'e', 's'}));
  uint8_t st = b.client.call(req, res);
  CHECK(st == hwbridge::kCallOk && res.success && strcmp(res.message.c_str(), "yes") == 0, "call: %u", st);
  // the request went out in the session's form: id 1, the empty Trigger request
  std::vector<std::pair<hwbridge::Frame, Bytes> > sent = harness::frames_of(hw.take());
  const std::pair<uint8_t, Bytes> want = call_message<P>(0x20, 1, Bytes{1, 0});
  bool found = false;
  for (size_t i = 0; i < sent.size(); ++i) {
    found = found || (sent[i].first.type == FrameType::Reliable && sent[i].first.channel == want.first &&
                      sent[i].second == want.second);
  }
  CHECK(found, "service client: no request %s on channel %u", check::hex(want.second).c_str(), want.first);
  // NO_SERVICE
  hw.feed(host.ack(next_seq++));
  hw.feed(answer(Bytes{2, 0, 2}));
  st = b.client.call(req, res);
  CHECK(st == hwbridge::kCallNoService, "NO_SERVICE: %u", st);
  // a response that does not deserialize
  hw.feed(host.ack(next_seq++));
  hw.feed(answer(Bytes{3, 0, 0, 9}));
  st = b.client.call(req, res);
  CHECK(st == hwbridge::kCallBadResponse, "bad response: %u", st);
  // no answer within 300 ms (the host keeps the link alive, its ACK came)
  hw.feed(host.ack(next_seq++));
  hw.step_us = 200;
  for (int i = 0; i < 8; ++i) hw.feed(host.be(0, Bytes{0x02}));
  st = b.client.call(req, res, 300);
  CHECK(st == hwbridge::kCallTimeout, "timeout: %u", st);
  // a late answer to the timed-out call is ignored; the next call still works
  hw.feed(answer(Bytes{4, 0, 0, 0, 0, 0, 0, 0}));
  hw.feed(host.ack(next_seq++));
  hw.feed(answer(Bytes{5, 0, 0, 1, 0, 0, 0, 0}));
  st = b.client.call(req, res);
  CHECK(st == hwbridge::kCallOk && res.success, "call after a timeout: %u", st);
  // the link dies during a call: the call ends with the session
  hw.feed(host.ack(next_seq++));
  hw.step_us = 1000;
  st = b.client.call(req, res);
  CHECK(st == hwbridge::kCallSessionReset && !b.node.connected(), "call at link loss: %u", st);
  CHECK(b.node.stats().protocol_errors == 0, "service client: %u protocol errors", b.node.stats().protocol_errors);
  printf("service client%s: answered, NO_SERVICE, bad response, timeout, session reset\n", call_form<P>());
}


/** The golden profile with ACK_IN_DATA (the library's profiles announce it). */
struct AckInDataProfile : harness::GoldenProfile {
  static const uint8_t kFeatures = 3 | hwbridge::control::Features::ACK_IN_DATA;
};

/** ACK_IN_DATA negotiated (PROTOCOL.md 2.4, 2.12 P): the board answers a service request with
 * one frame that carries the request's ACK, takes the ACK of its answer from the host's next
 * request (its window of 1 frees before the request is handled), and sends no ACK frame; an
 * ACK in a heartbeat frees the window too. Against a host without the feature, the board sends
 * ACK frames as before. */
void ack_in_data() {
  for (int with = 1; with >= 0; --with) {
    hwbridge::NodeHandle_<harness::FakeHardware, AckInDataProfile> node;
    hwbridge::ServiceServer<std_srvs::Trigger> reset{"/reset", &harness::on_reset};  // channel 1
    harness::FakeHardware& hw = node.getHardware();
    Host host;
    node.setIdentity(0xcafef00dUL, 0);
    node.advertiseService(reset);
    hw.clock = 10000000;
    node.begin("acks", "");
    harness::connect_scripted(node, hw, host, with ? 15 : 7);
    CHECK(node.connected(), "ack_in_data: not connected");
    uint8_t last_answer = 0;
    for (uint8_t id = 1; id <= 3; ++id) {
      const uint8_t req_seq = host.rel_seq;
      Bytes request = host.rel(0, Bytes{0x20, 1, id, 0});  // SERVICE_REQUEST /reset
      if (with && id > 1) {  // the host's request carries the ACK of the last answer
        check::VecSink sink;
        hwbridge::FrameHeader h;
        h.type = FrameType::Reliable;
        h.frag = hwbridge::Frag::Whole;
        h.channel = 0;
        h.seq = req_seq;
        const Bytes body{0x20, 1, id, 0};
        hwbridge::write_frame(sink, h, body.data(), body.size(), &last_answer, 1, hwbridge::kCarryAck);
        request = sink.bytes;
      } else if (id > 1) {
        hw.feed(host.ack(last_answer));
      }
      hw.feed(request);
      node.spinOnce();
      std::vector<std::pair<hwbridge::Frame, Bytes> > fr = harness::frames_of(hw.take());
      int acks = 0, answers = 0;
      for (size_t i = 0; i < fr.size(); ++i) {
        const hwbridge::Frame& f = fr[i].first;
        if (f.type == FrameType::Ack) {
          ++acks;
          CHECK(f.seq == req_seq, "ack_in_data: ACK of %u, expected %u", f.seq, req_seq);
        } else if (f.type == FrameType::Reliable) {
          ++answers;
          last_answer = f.seq;
          CHECK(fr[i].second.size() >= 4 && fr[i].second[0] == 0x21 && fr[i].second[2] == id,
                "ack_in_data: call %u answered with %s", id, check::hex(fr[i].second).c_str());
          CHECK(f.acked == (with == 1) && (!f.acked || f.ack == req_seq), "ack_in_data: answer %u carries %d/%u",
                id, f.acked, f.ack);
        }
      }
      CHECK(answers == 1 && acks == (with ? 0 : 1), "ack_in_data (%s): call %u gave %d answers, %d ACK frames",
            with ? "on" : "off", id, answers, acks);
    }
    if (with) {  // the last answer acknowledged by a heartbeat that carries the ACK
      check::VecSink sink;
      hwbridge::FrameHeader h;
      h.type = FrameType::BestEffort;
      h.frag = hwbridge::Frag::Whole;
      h.channel = 0;
      h.seq = host.be_seq++;
      const uint8_t hb = 0x02;
      hwbridge::write_frame(sink, h, &hb, 1, &last_answer, 1, hwbridge::kCarryAck);
      const uint8_t req_seq = host.rel_seq;
      hw.feed(sink.bytes);
      hw.feed(host.rel(0, Bytes{0x20, 1, 9, 0}));
      node.spinOnce();
      std::vector<std::pair<hwbridge::Frame, Bytes> > fr = harness::frames_of(hw.take());
      CHECK(fr.size() == 1 && fr[0].first.type == FrameType::Reliable && fr[0].first.acked &&
                fr[0].first.ack == req_seq,
            "ack_in_data: after a heartbeat with the ACK, %zu frames", fr.size());
    }
    CHECK(node.stats().link_losses == 0 && node.stats().protocol_errors == 0, "ack_in_data: losses %u, errors %u",
          node.stats().link_losses, node.stats().protocol_errors);
  }
  printf("ack_in_data: answers carry the request's ACK, requests the answer's\n");
}

/** The golden board's entries (/chatter on channel 1, /reset on 2) on a node of profile P, with
 * a subscriber on channel 3, connected by a host of the given features. */
std::vector<std::string> g_heard;
void on_heard(const std_msgs::String& m) { g_heard.push_back(m.data.c_str()); }

template <class P>
struct CallBoard {
  hwbridge::NodeHandle_<harness::FakeHardware, P> node;
  hwbridge::Publisher<harness::Raw> chatter{"/chatter"};
  hwbridge::ServiceServer<std_srvs::Trigger> reset{"/reset", &harness::on_reset};
  hwbridge::Subscriber<std_msgs::String> heard{"/heard", &on_heard};
  Host host;
  CallBoard(uint8_t host_features, bool subscriber) : node() {
    harness::FakeHardware& hw = node.getHardware();
    node.setIdentity(0xcafef00dUL, 0);
    node.advertise(chatter);
    node.advertiseService(reset);  // its channel carries calls: the subscriber after it still hears
    if (subscriber) node.subscribe(heard);
    hw.clock = 10000000;
    node.begin("calls", "");
    harness::connect_scripted(node, hw, host, host_features);
    CHECK(node.connected(), "call board not connected");
  }
  /** Feeds bytes, spins once, returns the frames written. */
  std::vector<std::pair<hwbridge::Frame, Bytes> > exchange(const Bytes& in) {
    node.getHardware().feed(in);
    node.spinOnce();
    return harness::frames_of(node.getHardware().take());
  }
};

/** The golden board's answers to the calls of native_session.json's extra vectors (PROTOCOL.md
 * 2.12 P and Q), byte for byte: the board and the host both with ACK_IN_DATA, and then also with
 * SERVICE_CHANNELS. */
struct AckInDataOwnChannelProfile : harness::GoldenProfile {
  static const uint8_t kFeatures =
      3 | hwbridge::control::Features::ACK_IN_DATA | hwbridge::control::Features::SERVICE_CHANNELS;
};

/** The same with SHORT_CALLS too (2.12 R). */
struct AckInDataShortProfile : harness::GoldenProfile {
  static const uint8_t kFeatures = 3 | hwbridge::control::Features::ACK_IN_DATA |
                                   hwbridge::control::Features::SERVICE_CHANNELS |
                                   hwbridge::control::Features::SHORT_CALLS;
};

template <class P>
void replay_calls(const Transcript& tr, const char* prefix, uint8_t host_features) {
  CallBoard<P> b(host_features, false);
  for (int call = 1; call <= 2; ++call) {
    char req[64], res[64];
    snprintf(req, sizeof req, "%s_request_%d", prefix, call);
    snprintf(res, sizeof res, "%s_response_%d", prefix, call);
    b.node.getHardware().feed(tr.get(req, 'h'));
    b.node.spinOnce();
    expect_bytes(res, b.node.getHardware().take(), tr.get(res, 'd'));
  }
}

/** SERVICE_CHANNELS (PROTOCOL.md 2.8): the vectors' calls answered byte for byte; a request on
 * the server's channel answered there, a SERVICE_REQUEST on channel 0 answered too (for a
 * channel without a service: NO_SERVICE on channel 0), a call message shorter than its fields a
 * protocol error, a
 * subscriber's messages still delivered in a sketch with a service; against a host without the
 * feature, answers as SERVICE_RESPONSE and a message on the service's channel is no call. */
void service_channels(const Transcript& tr) {
  replay_calls<AckInDataProfile>(tr, "ack_in_data", 15);
  replay_calls<AckInDataOwnChannelProfile>(tr, "service_channel", 31);

  CallBoard<OwnChannelProfile> b(3 | 4 | 16, true);
  const hwbridge::Counter errors = b.node.stats().protocol_errors;
  const Bytes trigger_ok{0, 1, 2, 0, 0, 0, 'o', 'k'};  // status OK, success, "ok"
  std::vector<std::pair<hwbridge::Frame, Bytes> > fr = b.exchange(b.host.rel(2, Bytes{7, 0}));
  Bytes want{7, 0};
  want.insert(want.end(), trigger_ok.begin(), trigger_ok.end());
  CHECK(fr.size() == 2 && fr[0].first.type == FrameType::Ack && fr[1].first.type == FrameType::Reliable &&
            fr[1].first.channel == 2 && fr[1].second == want,
        "own channel: %zu frames, the answer %s", fr.size(), fr.empty() ? "" : check::hex(fr.back().second).c_str());
  b.node.getHardware().feed(b.host.ack(fr[1].first.seq));
  // a SERVICE_REQUEST all the same: answered (on the service's channel: the session's form)
  fr = b.exchange(b.host.rel(0, Bytes{0x20, 2, 8, 0}));
  want[0] = 8;
  CHECK(fr.size() == 2 && fr[1].first.channel == 2 && fr[1].second == want, "SERVICE_REQUEST in the session: %s",
        fr.empty() ? "" : check::hex(fr.back().second).c_str());
  b.node.getHardware().feed(b.host.ack(fr[1].first.seq));
  // a SERVICE_REQUEST for a channel with no service (the publisher's): NO_SERVICE as a
  // SERVICE_RESPONSE, which a caller always reads
  fr = b.exchange(b.host.rel(0, Bytes{0x20, 1, 4, 0}));
  CHECK(fr.size() == 2 && fr[1].first.channel == 0 && fr[1].second == (Bytes{0x21, 1, 4, 0, 2}),
        "SERVICE_REQUEST for no service: %s", fr.empty() ? "" : check::hex(fr.back().second).c_str());
  b.node.getHardware().feed(b.host.ack(fr[1].first.seq));
  // a message shorter than a request id: a protocol error, acknowledged, no answer
  fr = b.exchange(b.host.rel(2, Bytes{9}));
  CHECK(fr.size() == 1 && fr[0].first.type == FrameType::Ack && b.node.stats().protocol_errors == errors + 1,
        "a 1-byte request: %zu frames, %u errors", fr.size(), b.node.stats().protocol_errors);
  // the subscriber on channel 3 still hears its topic
  g_heard.clear();
  fr = b.exchange(b.host.rel(3, Bytes{2, 0, 0, 0, 'h', 'i'}));
  CHECK(g_heard.size() == 1 && g_heard[0] == "hi", "the subscriber heard %zu messages", g_heard.size());

  CallBoard<OwnChannelProfile> old(3 | 4, false);  // a host without SERVICE_CHANNELS
  fr = old.exchange(old.host.rel(0, Bytes{0x20, 2, 5, 0}));
  want = Bytes{0x21, 2, 5, 0};
  want.insert(want.end(), trigger_ok.begin(), trigger_ok.end());
  CHECK(fr.size() == 2 && fr[1].first.channel == 0 && fr[1].second == want, "without the feature: %s",
        fr.empty() ? "" : check::hex(fr.back().second).c_str());
  old.node.getHardware().feed(old.host.ack(fr[1].first.seq));
  const hwbridge::Counter dropped = old.node.stats().dropped_messages;
  fr = old.exchange(old.host.rel(2, Bytes{6, 0}));
  CHECK(fr.size() == 1 && fr[0].first.type == FrameType::Ack && old.node.stats().dropped_messages == dropped + 1,
        "without the feature a message on the service's channel was taken for a call");
  CHECK(b.node.stats().link_losses == 0 && old.node.stats().protocol_errors == 0, "service channels: losses, errors");
  printf("service channels: the vectors' answers, calls on the service's channel, SERVICE_REQUEST still "
         "answered, calls shorter than their head refused, subscribers served; old hosts get SERVICE_RESPONSE\n");
}

/** SHORT_CALLS (PROTOCOL.md 2.8): the vectors' calls answered byte for byte (2.12 R); a request
 * is its id in one byte (bit 7 ignored) and the body, an OK answer the id and the body, another
 * status id | 0x80 and the status; a SERVICE_REQUEST is answered in the short form when its id
 * fits in 7 bits, else NO_SERVICE as a SERVICE_RESPONSE; an empty request is a protocol error;
 * a host with SERVICE_CHANNELS alone gets the two- and three-byte heads. */
void short_call_heads(const Transcript& tr) {
  replay_calls<AckInDataShortProfile>(tr, "short_call", 63);

  CallBoard<ShortCallsProfile> b(3 | 4 | 16 | 32, false);
  const hwbridge::Counter errors = b.node.stats().protocol_errors;
  const Bytes trigger_ok{1, 2, 0, 0, 0, 'o', 'k'};  // success, "ok"
  Bytes want{7};
  want.insert(want.end(), trigger_ok.begin(), trigger_ok.end());
  std::vector<std::pair<hwbridge::Frame, Bytes> > fr = b.exchange(b.host.rel(2, Bytes{7}));
  CHECK(fr.size() == 2 && fr[1].first.type == FrameType::Reliable && fr[1].first.channel == 2 && fr[1].second == want,
        "short call: %zu frames, the answer %s", fr.size(), fr.empty() ? "" : check::hex(fr.back().second).c_str());
  b.node.getHardware().feed(b.host.ack(fr[1].first.seq));
  // bit 7 of a request's byte is reserved: ignored, the answer echoes the id
  fr = b.exchange(b.host.rel(2, Bytes{0x80 | 9}));
  want[0] = 9;
  CHECK(fr.size() == 2 && fr[1].first.channel == 2 && fr[1].second == want, "a request with bit 7: %s",
        fr.empty() ? "" : check::hex(fr.back().second).c_str());
  b.node.getHardware().feed(b.host.ack(fr[1].first.seq));
  // a SERVICE_REQUEST with an id of 7 bits: answered on the channel, short
  fr = b.exchange(b.host.rel(0, Bytes{0x20, 2, 100, 0}));
  want[0] = 100;
  CHECK(fr.size() == 2 && fr[1].first.channel == 2 && fr[1].second == want, "SERVICE_REQUEST, id 100: %s",
        fr.empty() ? "" : check::hex(fr.back().second).c_str());
  b.node.getHardware().feed(b.host.ack(fr[1].first.seq));
  // ... with a larger id, which the short answer cannot carry: NO_SERVICE as a SERVICE_RESPONSE
  fr = b.exchange(b.host.rel(0, Bytes{0x20, 2, 0x2c, 0x01}));
  CHECK(fr.size() == 2 && fr[1].first.channel == 0 && fr[1].second == (Bytes{0x21, 2, 0x2c, 0x01, 2}),
        "SERVICE_REQUEST, id 300: %s", fr.empty() ? "" : check::hex(fr.back().second).c_str());
  b.node.getHardware().feed(b.host.ack(fr[1].first.seq));
  // an empty message on the server's channel: a protocol error, acknowledged, no answer
  fr = b.exchange(b.host.rel(2, Bytes{}));
  CHECK(fr.size() == 1 && fr[0].first.type == FrameType::Ack && b.node.stats().protocol_errors == errors + 1,
        "an empty request: %zu frames, %u errors", fr.size(), b.node.stats().protocol_errors);
  CHECK(b.node.stats().link_losses == 0, "short calls: link lost");

  CallBoard<ShortCallsProfile> old(3 | 4 | 16, false);  // a host with SERVICE_CHANNELS alone
  fr = old.exchange(old.host.rel(2, Bytes{5, 0}));
  want = Bytes{5, 0, 0};
  want.insert(want.end(), trigger_ok.begin(), trigger_ok.end());
  CHECK(fr.size() == 2 && fr[1].first.channel == 2 && fr[1].second == want, "a host without SHORT_CALLS: %s",
        fr.empty() ? "" : check::hex(fr.back().second).c_str());
  CHECK(old.node.stats().protocol_errors == 0, "a host without SHORT_CALLS: errors");
  printf("short calls: the vectors' answers, one-byte heads, bit 7 ignored in requests, SERVICE_REQUEST "
         "answered short or NO_SERVICE, empty calls refused; hosts without it get the long heads\n");
}

}  // namespace

#endif  // HWBRIDGE_TESTS_SESSION_SERVICES_H
