// The bodies of NodeHandle_, part of node_impl.h: input: frames, the control messages, the
// handshake (2.5), the table's answers.
// Included inside namespace hwbridge by node_impl.h only, which defines HWB_NODE and HWB_SELF.
#ifndef HWBRIDGE_NODE_INPUT_H
#define HWBRIDGE_NODE_INPUT_H
#ifndef HWB_NODE
#error "hwbridge/node/*.h are parts of node_impl.h: include HwBridge.h"
#endif

// ---------------------------------------------------------------------------------------------
// Input

HWB_NODE void HWB_SELF::onFrame(const Frame& f) {
  if (kAckInData && f.acked && established()) {  // an ACK in a data frame (ACK_IN_DATA): first, as if before it
    Frame a = f;
    a.seq = f.ack;
    a.size = 0;
    rel_tx_.on_ack(a, now_);
  }
  if (f.type == FrameType::BestEffort) {
    onBestEffort(f);
    return;
  }
  if (!established()) {
    ++stats_.ignored_frames;
    return;
  }
  last_rx_ = tick_;
  if (f.type == FrameType::Ack) {
    rel_tx_.on_ack(f, now_);
    return;
  }
  if (rel_rx_.receive(f) != Received::Deliver) return;
  deliver(f);
  // frames held early (a window above 1) that are now in order; a teardown in onMessage
  // empties the receiver, which ends this
  Frame h;
  while (rel_rx_.pop(&h)) deliver(h);
}

/** A frame its stream accepted: through reassembly to onMessage. */
HWB_NODE void HWB_SELF::deliver(const Frame& f) {
  Message m;
  if (reasm_.feed(f, &m)) onMessage(m, f.type == FrameType::Reliable);
}

HWB_NODE void HWB_SELF::onBestEffort(const Frame& f) {
  const uint8_t* p = f.payload;
  // a HELLO, as far as its session id (the rest is checked in onControl)
  if (f.channel == kControlChannel && f.size >= 8 && p[0] == board::Hello::kOpcode &&
      board::Hello::version(p) == control::PROTOCOL_VERSION) {
    const uint32_t peer = board::Hello::session(p);  // a HELLO: a new session has its own seq space
    if (peer != be_peer_ && peer != id_) {
      be_peer_ = peer;
      be_rx_.resync();
      reasm_.reset(FrameType::BestEffort);
    }
  }
  if (be_rx_.accept(f.seq)) deliver(f);
}

HWB_NODE void HWB_SELF::onMessage(const Message& m, bool reliable) {
  if (m.channel == kControlChannel) {
    onControl(m.data, m.size, reliable);
  } else if (established()) {
    last_rx_ = tick_;
    if (on_data_) {
      on_data_(this, m);
    } else {  // this board subscribes to nothing
      ++stats_.dropped_messages;
    }
  } else {
    ++stats_.ignored_frames;
  }
}

HWB_NODE void HWB_SELF::onData(const Message& m) {
  Entry* e = state_ == kConnected ? entryOn(m.channel, kSubscriber) : nullptr;
  size_t len = m.size;
  if (e == nullptr || e->hook_(e, Entry::kOpDeliver, m.data, &len, nullptr) != nullptr) {
    ++stats_.dropped_messages;
  }
}

/** Whether a service request can be answered now. When there is no room for the answer (a
 * message waits for the reliable window) the request is taken back unacknowledged, and the
 * host sends it again after its RTO; only a request of fragments (a board with reassembly) or
 * one released from the held frames cannot be: counted, and the host's call times out. Until
 * it comes again, the board's own reliable messages leave the buffer to its answer (a sketch
 * publishing whenever a slot frees would otherwise take it first every time). */
HWB_NODE bool HWB_SELF::admitRequest() {
  if (!txFree()) {
    if (reasm_.unfeed() && rel_rx_.refuse()) {
      flags_ |= kAnswerOwed;
    } else {
      ++stats_.tx_refused;
    }
    return false;
  }
  flags_ &= static_cast<uint8_t>(~kAnswerOwed);
  return true;
}

/** A message on a channel other than 0 in a sketch with a service (channelThunk): with
 * SERVICE_CHANNELS (2.8) a service entry's channel carries its calls, a request on a server's
 * and a response on a client's (with SHORT_CALLS their heads are one byte); any other channel
 * is a subscriber's. */
HWB_NODE void HWB_SELF::onChannel(const Message& m) {
  Entry* e = entryAt(m.channel);
  if (e == nullptr || e->kind_ < kServiceServer || !(features_ & control::Features::SERVICE_CHANNELS)) {
    onData(m);
    return;
  }
  const uint8_t* p = m.data;
  const size_t n = m.size;
  // The head: the request id, in one byte with SHORT_CALLS (where a response's bit 7 says its
  // status follows; none: OK), else in two (a response's status after it).
  const bool brief = shortCalls();
  size_t h = brief ? 1 : kCallHead;
  if (e->kind_ == kServiceServer) {
    if (n < h) {
      protocolError();
    } else if (admitRequest()) {
      onServiceRequest(m.channel, brief ? (p[0] & kShortIdMask) : wire::get16(p), p + h, n - h);
    }
    return;
  }
  if (!brief || (n != 0 && (p[0] & kStatusFollows))) ++h;  // the status's place, h - 1
  if (n < h || (h > 1 && p[h - 1] > control::ServiceStatus::NO_SERVICE)) {
    protocolError();
  } else if (e == call_entry_) {  // else late, or not ours
    on_response_(this, p, n | kOwnChannel | (brief ? kShortHead : 0));
  }
}

HWB_NODE void HWB_SELF::onControl(const uint8_t* p, size_t n, bool reliable) {
  // the fixed size of each opcode's fields (0: unknown); variable ones give their minimum
  // (board's view: 0 for what only a board sends); from the schema, in flash for opcodes 0..7
  static const uint8_t kBe[8] HWBRIDGE_PROGMEM = {0, board::Hello::kMinSize, board::Heartbeat::kMinSize, 0, board::TimeResponse::kMinSize, board::Goodbye::kMinSize, board::HostTimeRequest::kMinSize, 0};
  if (n == 0) {
    protocolError();
    return;
  }
  const uint8_t op = p[0];
  uint8_t need = 0;
  if (op < 8) {
    need = flash_byte(reinterpret_cast<const char*>(kBe) + op);
  } else if (op == board::TopicAck::kOpcode) {
    need = board::TopicAck::kMinSize;
  } else if (op == board::Ready::kOpcode) {
    need = board::Ready::kMinSize;
  } else if (op == board::ServiceRequest::kOpcode) {
    need = board::ServiceRequest::kMinSize;
  } else if (op == board::ServiceResponse::kOpcode) {
    need = board::ServiceResponse::kMinSize;
  } else if (op == board::ParamValue::kOpcode) {
    need = board::ParamValue::kMinSize;
  } else if (op == board::Log::kOpcode) {
    need = board::Log::kMinSize;
  }
  if (need == 0 || n < need || (op < control::FIRST_OPCODE_RELIABLE) == reliable) {  // unknown, short, or wrong stream
    protocolError();
    return;
  }
  // a sign of life (2.9), a HELLO too; before a session it counts for nothing (establish sets it)
  last_rx_ = tick_;
  if (op == board::Hello::kOpcode) {
    onHello(p);
    return;
  }
  if (!established()) {
    ++stats_.ignored_frames;
    return;
  }
  switch (op) {
    case board::Heartbeat::kOpcode:
      break;
    case board::TimeResponse::kOpcode:  // only a board that asks (kTimeSyncMs) reads the answers
      if (Profile::kTimeSyncMs) onTimeResponse(p);
      break;
    case board::Goodbye::kOpcode:
      ++stats_.peer_resets;
      teardown();
      break;
    case board::HostTimeRequest::kOpcode: {  // t1 echoed, t2 = t3 = now
      if (!(Profile::kFeatures & control::Features::TIME_SYNC)) break;
      const uint32_t sec = board::HostTimeRequest::t1_sec(p), nsec = board::HostTimeRequest::t1_nsec(p);
      if (!flag(kTimeSynced)) {  // a first estimate of host time: t1 plus the one-way delay
        host_sec_ = sec;
        host_nsec_ = nsec;
        board_ref_ = now_;
      }
      uint8_t r[board::HostTimeResponse::kMinSize];
      board::HostTimeResponse::put(r, sec, nsec, now_, now_);
      sendControlBe(r, sizeof r);
      break;
    }
    case board::TopicAck::kOpcode:
      onTopicAck(p, n);
      break;
    case board::Ready::kOpcode:
      if (state_ != kConfiguring) break;
      {
        uint8_t accepted = 0;
        for (Entry* e = entries_; e; e = e->next_) accepted = static_cast<uint8_t>(accepted + e->accepted_);
        if (accepted != board::Ready::accepted(p)) protocolError();
      }
      state_ = kConnected;
      time_.schedule(tick_, 0);  // the first time request right after CONNECTED
      break;
    case board::ServiceRequest::kOpcode:
      if (!admitRequest()) break;
      if (on_request_) {
        on_request_(this, p, n);
      } else {  // this board serves nothing: NO_SERVICE
        board::ServiceResponse::put(tx_, board::ServiceRequest::channel(p), board::ServiceRequest::request_id(p),
                                    control::ServiceStatus::NO_SERVICE);
        pending_ch_ = kControlChannel;
        pending_len_ = board::ServiceResponse::kBody;
      }
      break;
    case board::ServiceResponse::kOpcode:  // only to a board with a service client
      if (on_response_ && board::ServiceResponse::status(p) <= control::ServiceStatus::NO_SERVICE) {
        on_response_(this, p, n);
      } else {
        protocolError();
      }
      break;
    case board::ParamValue::kOpcode:
      if (on_param_) {
        on_param_(this, p, n);
      } else {  // this board asked for no parameter
        protocolError();
      }
      break;
    case board::Log::kOpcode:  // from the host: never sent to a board without HOST_LOG
      if (!(Profile::kFeatures & control::Features::HOST_LOG) || board::Log::level(p) > control::LogLevel::FATAL) {
        protocolError();
      } else if (log_cb_ != nullptr) {
        log_cb_(board::Log::level(p), reinterpret_cast<const char*>(p + board::Log::kText), n - board::Log::kText);
      }
      break;
    default:  // an opcode only a board sends
      protocolError();
  }
}

HWB_NODE void HWB_SELF::onHello(const uint8_t* p) {
  typedef board::Hello H;
  const uint32_t session = H::session(p);
  const uint32_t peer_session = H::peer_session(p);
  if (H::version(p) != control::PROTOCOL_VERSION || H::role(p) != control::Role::HOST) {  // another version, or the peer is a board (or an echo)
    protocolError();
    return;
  }
  if (established() && (session != peer_ || peer_session != id_)) {
    ++stats_.peer_resets;  // the host restarted, or dropped the session
    teardown();
  }
  if (!established()) {
    if (H::mtu(p) < (kFragments ? kMinMtu : Profile::kTxBuffer) || H::window(p) == 0 || H::max_message(p) == 0 || session == 0) {
      protocolError();
      return;
    }
    peer_ = session;
    if (peer_session == id_) establish(p);
  }
  if (!(H::flags(p) & control::HelloFlags::ESTABLISHED)) sendHello();
}

HWB_NODE void HWB_SELF::establish(const uint8_t* h) {
  typedef board::Hello H;
  const uint16_t host_mtu = H::mtu(h);
  mtu_ = kFixedMtu || host_mtu > Profile::kMtu ? Profile::kMtu : host_mtu;
  // the host's window is at least 1 (onHello refused 0)
  uint8_t window = Profile::kWindow == 1 || H::window(h) > Profile::kWindow ? Profile::kWindow : H::window(h);
  if (window > kMaxWindow) window = kMaxWindow;
  const uint32_t peer_max = H::max_message(h);
  peer_max_ = peer_max > 0xFFFFUL ? 0xFFFFu : static_cast<uint16_t>(peer_max);
  features_ = static_cast<uint8_t>(H::features(h) & kOwnFeatures);
  rel_tx_.reset(isn_, window, kFixedMtu ? Profile::kMtu : mtu_);
  rel_rx_.reset(H::isn(h), window);
  reasm_.reset(FrameType::Reliable);
  // the receiver's limit becomes the negotiated MTU (2.5); for a board that does not fragment
  // and whose largest message fills its MTU, that is always its own (smaller host MTUs refused)
  if (!kFixedMtu) dec_.set_max_payload(mtu_);
  // every entry is unaccepted: teardown cleared them, and only a session accepts one
  table_pos_ = 0;
  pending_len_ = 0;
  state_ = kConfiguring;
  timer_ = last_rx_ = tick_;
  ++stats_.sessions;
}

/** Ends the session (2.10), or starts the first handshake: pending requests fail, the reliable
 * stream is dropped, a new ISN is drawn, and a HELLO goes out at the next timer run. */
HWB_NODE void HWB_SELF::teardown() {
  const bool was = established();
  state_ = kHandshake;
  peer_ = 0;
  peer_max_ = kMinMtu;
  mtu_ = Profile::kMtu;
  if (!kFixedMtu) dec_.set_max_payload(Profile::kMtu);
  if (was) reasm_.reset(FrameType::Reliable);
  pending_len_ = 0;
  flags_ = static_cast<uint8_t>(flags_ & ~(kTimeSynced | kAnswerOwed));
  time_.clear();  // time samples of the last session's host
  features_ = 0;
  // a new ISN per session: the random session id mixed with the time (no generator state kept)
  isn_ = flag(kFixed) ? fixed_isn_ : static_cast<uint8_t>(id_ ^ now_ ^ now_ >> 8);
  rel_tx_.reset(isn_, Profile::kWindow, Profile::kMtu);
  timer_ = tick_;
  hello_wait_ = 0;  // a HELLO at the next timer run, then after 50, 100, 200, 250, 250... ms
  for (Entry* e = entries_; e; e = e->next_) e->accepted_ = false;
  // through the pointers serviceClient and requestParam set: a sketch without service clients
  // or parameters links none of it
  if (on_response_) on_response_(this, nullptr, kCallSessionReset);
  if (on_param_) on_param_(this, nullptr, kParamSessionReset);
}

HWB_NODE void HWB_SELF::onTopicAck(const uint8_t* p, size_t n) {
  typedef board::TopicAck A;
  const uint8_t status = A::status(p);
  Entry* e = entryAt(A::channel(p));
  if (e == nullptr || status > control::TopicStatus::INVALID ||
      (status != control::TopicStatus::ACCEPTED && n < A::kHostMd5End)) {
    protocolError();
    return;
  }
  if (status == control::TopicStatus::ACCEPTED) {
    e->accepted_ = true;
    return;
  }
  protocolError();
  if (status == control::TopicStatus::MISMATCH) {
    ++stats_.mismatches;
  } else {
    ++stats_.refused_entries;
  }
}

#endif  // HWBRIDGE_NODE_INPUT_H
